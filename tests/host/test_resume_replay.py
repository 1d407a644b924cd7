"""Replay protection across a host restart: a restarted host resumes it from the log
(`Store.last_seqs`, `Store.recent_frames`, `ReplayGuard.seed`), so frames logged before
the restart are duplicates or replays after it, exactly as if the host had not stopped;
a fresh log starts empty; a baseline an operator accepted survives the restart."""
from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from host_rig import KEYS
from ropemon.station.decoder import DUPLICATE_MEMORY, SEQ_COUNT_BITS, ReplayGuard, StreamDecoder, frame_bytes
from ropemon.station.monitor import MonitorView
from ropemon.station.pipeline import AcceptRewound, HoistPipeline, station_listeners
from ropemon.station.protocol import decode_raw, encode_frame
from ropemon.station.store import Store
from ropemon.lab.vserial import VirtualPort

ROOT = Path(__file__).resolve().parents[2]


def boot(b: int, k: int) -> int:
    return (b << SEQ_COUNT_BITS) | k


def w(node: int, seq: int, tension: int = 500) -> bytes:
    return encode_frame(node=node, seq=seq, time_ms=seq & 0xFFFF, ropes=[(tension, tension, tension, 0)] * 4,
                        key=KEYS[node])[1]


def stream(node: int, b: int, counts) -> bytes:
    return b"".join(w(node, boot(b, k)) for k in counts)


def counts(s: HoistPipeline) -> dict[str, tuple[int, int, int, int]]:
    return {n: (d.counts.frames_ok, d.counts.duplicate, d.counts.replayed, d.counts.rewound)
            for n, d in s.decoders.items()}


def station(keys, store):
    view = MonitorView()
    return HoistPipeline(keys, station_listeners(None, store, view), resume_from=store), view


def accept(s: HoistPipeline, node: int, operator: str) -> None:
    s.submit(AcceptRewound(operator, "test", node=node))
    s.pump()


def logged(db: Path) -> list[tuple[int, int]]:
    con = sqlite3.connect(db)
    try:
        return con.execute("SELECT node, seq FROM frames ORDER BY id").fetchall()
    finally:
        con.close()


def test_frame_bytes_are_the_received_bytes():
    for seq, ropes in ((0, 0), (boot(3, 17), 1), (2**32 - 1, 4)):
        raw, _ = encode_frame(node=2, seq=seq, ropes=[(1, -2, 3, 65535)] * ropes, depth_mm=-5, key=KEYS[2])
        assert frame_bytes(decode_raw(raw, KEYS)) == raw


def test_seeded_guard_refuses_what_it_was_seeded_with():
    frames = [decode_raw(encode_frame(node=1, seq=boot(3, k), ropes=[(k,) * 4], key=KEYS[1])[0], KEYS)
              for k in range(10)]
    g = ReplayGuard(memory=4)
    g.seed({1: boot(3, 9)}, {1: frames})
    assert g.check(1, boot(3, 9), frame_bytes(frames[9])) is ReplayGuard.DUPLICATE   # a radio retry
    assert g.check(1, boot(3, 6), frame_bytes(frames[6])) is ReplayGuard.DUPLICATE   # within memory
    assert g.check(1, boot(3, 5), frame_bytes(frames[5])) is ReplayGuard.REPLAYED    # beyond it
    assert g.check(1, boot(3, 9), b"other bytes") is ReplayGuard.REPLAYED
    assert g.check(1, boot(2, 99), None) is ReplayGuard.REWOUND and g.rewound == {1: (3, 2)}
    assert g.check(1, boot(3, 10), None) is ReplayGuard.ACCEPTED
    assert g.check(2, 0, None) is ReplayGuard.ACCEPTED                       # a node not seeded
    g.seed({2: boot(9, 0)})                                                  # seen already: kept
    assert g.check(2, 1, None) is ReplayGuard.ACCEPTED
    with pytest.raises(ValueError, match="node 3: seq -1"):
        g.seed({3: -1})
    with pytest.raises(ValueError, match="one of node 1"):
        ReplayGuard().seed({2: 5}, {2: frames[:1]})


def test_restarted_session_counts_logged_frames_as_before_and_stores_only_new_ones(tmp_path):
    """Session 1 logs boot 3 counts 0..99; it stops. Session 2 on the same log gets the whole
    recording again (both receivers), then newer frames: the same counts, stored frames and
    refusals as one session that never stopped."""
    db = tmp_path / "hoist.db"
    first, again, newer = stream(1, 3, range(100)), stream(1, 3, range(100)), stream(1, 3, range(100, 130))
    other = stream(2, 0, range(10))

    with Store(db) as store:
        s1, s1_view = station(KEYS, store)
        assert s1.resumed == {} and s1.resumed_text() is None
        s1.feed("pithead", first + other)
        s1.feed("mid-shaft", first)
        s1.close()
    assert len(logged(db)) == 110

    with Store(db) as store:
        s2, s2_view = station(KEYS, store)
        assert s2.resumed == {1: boot(3, 99), 2: boot(0, 9)}
        assert s2.resumed_text() == ("resumed replay protection from the log: node 1 at boot 3 count 99, "
                                     "node 2 at boot 0 count 9")
        s2.feed("pithead", again + newer)
        s2.feed("mid-shaft", again + newer)
        s2.feed("pithead", other + w(1, boot(2, 5)))   # and a recording of an older boot
        s2.tick()
        s2.close()
        assert s2_view.refused == {1: (3, 2)}
        assert s2_view.frames == 30
        # the last DUPLICATE_MEMORY logged frames are radio copies, the older ones replays
        dup = DUPLICATE_MEMORY
        assert counts(s2) == {"pithead": (30, dup + 10, 100 - dup + 1, 1), "mid-shaft": (30, dup, 100 - dup, 0)}
        assert [e for e in store.events() if e["kind"] == "link_integrity"]   # the replays raised the alarm

    rows = logged(db)
    assert len(rows) == len(set(rows)) == 140                            # nothing stored twice
    assert rows[110:] == [(1, boot(3, k)) for k in range(100, 130)]

    # The same input to one session that never stopped.
    with Store(tmp_path / "never-stopped.db") as store:
        s, s_view = station(KEYS, store)
        s.feed("pithead", first + other)
        s.feed("mid-shaft", first)
        before = counts(s)
        s.feed("pithead", again + newer)
        s.feed("mid-shaft", again + newer)
        s.feed("pithead", other + w(1, boot(2, 5)))
        s.close()
        after = {n: tuple(a - b for a, b in zip(c, before[n])) for n, c in counts(s).items()}
        assert after == counts(s2)
    assert logged(tmp_path / "never-stopped.db") == rows


def test_fresh_log_and_logs_without_keys_resume_nothing(tmp_path):
    with Store(tmp_path / "fresh.db") as store:
        s, s_view = station(KEYS, store)
        assert s.resumed == {}
        s.feed("pithead", stream(1, 3, range(5, 10)))
        assert s_view.frames == 5
        s.close()
    # Frames logged without keys (authenticated NULL) prove nothing: a keyed session starts empty.
    with Store(tmp_path / "nokey.db") as store:
        s, s_view = station(None, store)
        s.feed("pithead", stream(1, 3, range(100)))
        s.close()
        assert s.resumed == {}
    with Store(tmp_path / "nokey.db") as store:
        assert store.last_seqs() == {}
        s, s_view = station(KEYS, store)
        assert s.resumed == {}
        s.feed("pithead", stream(1, 3, range(10)))
        assert s_view.frames == 10
    # Without keys nothing is checked, so nothing is resumed either.
    with Store(tmp_path / "fresh.db") as store:
        s, s_view = station(None, store)
        assert s.resumed == {}
        s.feed("pithead", stream(1, 3, range(10)))
        assert s_view.frames == 10


def test_an_accepted_rewind_survives_the_restart_and_a_new_one_still_needs_the_operator(tmp_path):
    db = tmp_path / "hoist.db"
    with Store(db) as store:
        s, s_view = station(KEYS, store)
        for rx in ("pithead", "mid-shaft"):
            s.feed(rx, stream(1, 7, range(50)))
            s.feed(rx, stream(1, 0, range(3)))              # the node's flash was wiped: refused
        assert s.hub.rewound() == {1: (7, 0)}
        accept(s, 1, "alice")
        s.feed("pithead", stream(1, 0, range(3, 20)))       # boot 0 count 3 is the new baseline
        s.feed("mid-shaft", stream(1, 0, range(3, 20)))     # of both receivers: logged once
        s.close()
        reb = [e for e in store.events() if e["action"] == "rebase"]
        assert len(reb) == 1
        assert (reb[0]["node"], reb[0]["value"], reb[0]["threshold"]) == (1, boot(0, 3), boot(7, 49))
        assert "boot 0 count 3 taken as its new baseline (was boot 7 count 49" in reb[0]["message"]
        assert store.last_seqs() == {1: boot(0, 19)}

    with Store(db) as store:
        s, s_view = station(KEYS, store)
        assert s.resumed == {1: boot(0, 19)}                # not boot 7: the accepted baseline holds
        s.feed("pithead", stream(1, 0, range(10, 30)))
        assert s_view.frames == 10 and s.hub.rewound() == {}
        assert counts(s)["pithead"] == (10, 10, 0, 0)
        s.feed("pithead", w(1, boot(0, 5), tension=9))     # a replay within the baseline's boot
        assert counts(s)["pithead"][2:] == (1, 0)
        s.feed("pithead", stream(1, 1, range(5)))           # the node reboots: boot 1
        s.close()

    # A recording of boot 0 played in after the next restart: refused, until an operator accepts.
    with Store(db) as store:
        s, s_view = station(KEYS, store)
        assert s.resumed == {1: boot(1, 4)}
        s.feed("pithead", stream(1, 0, range(2)))
        assert s.hub.rewound() == {1: (1, 0)} and s_view.frames == 0
        accept(s, 1, "bob")
        s.feed("pithead", stream(1, 0, range(2, 4)))
        assert s_view.frames == 2 and s.hub.rewound() == {}
        s.close()
        reb = [e for e in store.events() if e["action"] == "rebase"]
        assert [(e["value"], e["threshold"]) for e in reb] == [(boot(0, 3), boot(7, 49)), (boot(0, 2), boot(1, 4))]
        assert store.last_seqs() == {1: boot(0, 3)}


def test_rebase_whose_frame_was_not_stored_resumes_from_the_whole_history(tmp_path):
    """A `rebase` event without its frame (killed in between) must not open the node up:
    the whole history counts, so the node is refused again until re-accepted."""
    db = tmp_path / "hoist.db"
    with Store(db) as store:
        s, s_view = station(KEYS, store)
        s.feed("pithead", stream(1, 7, range(5)) + stream(1, 0, range(1)))
        accept(s, 1, "alice")
        s.feed("pithead", stream(1, 0, range(1, 4)))
        s.close()
    con = sqlite3.connect(db)
    with con:
        con.execute("DELETE FROM ropes WHERE frame_id IN (SELECT id FROM frames WHERE seq < ?)", (boot(1, 0),))
        con.execute("DELETE FROM frames WHERE seq < ?", (boot(1, 0),))
    con.close()
    with Store(db) as store:
        assert store.last_seqs() == {1: boot(7, 4)}
        s, s_view = station(KEYS, store)
        s.feed("pithead", stream(1, 0, range(4, 6)))
        assert s.hub.rewound() == {1: (7, 0)}


def wait_open(pid: int, paths: list[str], timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            opened = {os.readlink(fd) for fd in Path(f"/proc/{pid}/fd").iterdir()}
        except OSError:
            opened = set()
        if set(paths) <= opened:
            time.sleep(0.1)
            return
        time.sleep(0.05)
    raise AssertionError(f"monitor did not open {paths}")


def run_monitor(db: Path, frames: list[bytes]) -> str:
    """`ropemon monitor --db` on a pty receiver, fed `frames`, ended with Ctrl-C; its stderr."""
    key = db.parent / "node1.key"
    key.write_text(KEYS[1].hex())
    key.chmod(0o600)
    with VirtualPort("pit") as a:
        p = subprocess.Popen([sys.executable, "-m", "ropemon.cli", "monitor", "--port", f"pithead={a.port}",
                              "--db", str(db), "--key-file", f"1:{key}", "--refresh-hz", "20"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
        try:
            wait_open(p.pid, [a.port])
            for f in frames:
                a.write(f)
                time.sleep(0.005)
            time.sleep(1.0)
        finally:
            p.send_signal(signal.SIGINT)
            _, err = p.communicate(timeout=20)
    assert p.returncode == 130, err
    return err


def test_monitor_command_resumes_from_its_db(tmp_path):
    db = tmp_path / "hoist.db"
    err = run_monitor(db, [w(1, boot(3, k)) for k in range(20)])
    assert "resumed replay protection" not in err
    err = run_monitor(db, [w(1, boot(3, k)) for k in range(10, 30)])
    assert "ropemon monitor: resumed replay protection from the log: node 1 at boot 3 count 19" in err
    assert logged(db) == [(1, boot(3, k)) for k in range(30)]
    con = sqlite3.connect(db)
    last = con.execute("SELECT duplicate, replayed FROM link_stats WHERE receiver = 'pithead' AND node IS NULL "
                       "ORDER BY id DESC LIMIT 1").fetchone()
    con.close()
    assert last == (10, 0)
