"""The store's default commit latency is what docs/storage.md promises: a frame is committed
(stored, seen by a reader of the file) at most 0.5 s after it arrived, checked on each
`add_frame` and by `flush()`, or once 50 frames are pending. Measured on the store's clock
(a fake one here, so the test does not depend on the machine's load) and once in real time."""
import time

import pytest

from ropemon.station import store as store_mod
from ropemon.station.protocol import Rope, decode_raw, encode_frame
from ropemon.station.store import Store

PROMISED_S = 0.5      # docs/storage.md, "Durability"
MARGIN_S = 0.1


class FakeClock:
    """Stands in for the `time` module inside ropemon.station.store."""

    def __init__(self) -> None:
        self.t = 1000.0

    def monotonic(self) -> float:
        return self.t

    def time(self) -> float:
        return 1_760_000_000.0 + self.t

    def sleep(self, s: float) -> None:
        self.t += s


def frame(seq: int):
    raw, _ = encode_frame(node=1, seq=seq, time_ms=100 * seq, ropes=[Rope(3000, 2990, 3010, 4000)] * 4,
                          battery_mv=12000)
    return decode_raw(raw)


def stored_rows(db) -> int:
    """Frames a reader of the file sees: only what was committed."""
    with Store(db, readonly=True) as rd:
        return rd.db.execute("SELECT count(*) FROM frames").fetchone()[0]


@pytest.fixture
def clock(monkeypatch):
    c = FakeClock()
    monkeypatch.setattr(store_mod, "time", c)
    return c


def test_a_lone_frame_is_committed_within_the_promised_latency_on_flush(tmp_path, clock):
    db = tmp_path / "log.db"
    st = Store(db)                       # the defaults, as `ropemon monitor` and `serve` open it
    try:
        st.add_frame("pithead", frame(0), clock.time())
        assert (st.pending_frames, st.committed_frames, stored_rows(db)) == (1, 0, 0)
        clock.sleep(PROMISED_S - MARGIN_S)
        assert st.flush() == 0 and stored_rows(db) == 0        # not before its time: a batch
        clock.sleep(MARGIN_S + MARGIN_S)                         # 0.6 s after it arrived
        assert st.flush() == 1
        assert (st.pending_frames, st.committed_frames, stored_rows(db)) == (0, 1, 1)
    finally:
        st.close()


def test_the_next_frame_commits_a_batch_whose_oldest_is_due(tmp_path, clock):
    db = tmp_path / "log.db"
    st = Store(db)
    try:
        for k in range(5):                                       # 0.1 s apart, no flush in between
            st.add_frame("pithead", frame(k), clock.time())
            clock.sleep(0.1)
        assert stored_rows(db) == 0 and st.pending_frames == 5  # the oldest is 0.5 s old only now
        clock.sleep(MARGIN_S)
        st.add_frame("pithead", frame(5), clock.time())          # checked on each add_frame
        assert st.pending_frames == 0 and stored_rows(db) == 6
    finally:
        st.close()


def test_fifty_pending_frames_commit_at_once(tmp_path, clock):
    db = tmp_path / "log.db"
    st = Store(db)
    try:
        for k in range(49):
            st.add_frame("pithead", frame(k), clock.time())
        assert stored_rows(db) == 0
        st.add_frame("pithead", frame(49), clock.time())
        assert stored_rows(db) == 50 and st.pending_frames == 0
    finally:
        st.close()


def test_in_real_time_a_frame_is_stored_soon_after_the_bound(tmp_path):
    db = tmp_path / "log.db"
    st = Store(db)
    try:
        st.add_frame("pithead", frame(0), time.time())
        time.sleep(PROMISED_S + 0.15)
        st.flush()
        assert stored_rows(db) == 1 and st.committed_frames == 1
    finally:
        st.close()
