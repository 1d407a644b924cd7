"""One bad message must not stop the fleet historian: metrics the station cannot have sent (node
or rope numbers out of range, a frame_seq past SQLite's INTEGER, a tension not finite) are refused
and counted; a message the database still refuses is set aside, counted and acknowledged, the
others committed and acknowledged in order; a database that cannot be written keeps everything."""
from __future__ import annotations

import logging
import sqlite3
import time

import pytest

pytest.importorskip("paho.mqtt")

from ropemon.station.mqtt import sparkplug as sp  # noqa: E402
from ropemon.station.mqtt.fleet import Fleet, Historian  # noqa: E402
from scada_rig import wait  # noqa: E402


def ddata(node, seq: int, frame_seq, tension=12.5, rope=1, ts: int | None = None) -> bytes:
    p = sp.payload(seq % 256)
    ts = p.timestamp if ts is None else ts
    sp.add_metric(p, f"node{node}/frame_seq", sp.UINT64, frame_seq, ts)
    sp.add_metric(p, f"node{node}/rope{rope}/tension", sp.DOUBLE, tension, ts)
    return p.SerializeToString()


def rig(tmp_path, historian: Historian | None = None) -> tuple[Fleet, list[int]]:
    """A consumer never connected: its writer (not started yet, so that what the test queues first
    is one batch) driven through its queue, its PUBACKs noted."""
    fleet = Fleet(historian or Historian(tmp_path / "fleet.db"), port=1)
    acks: list[int] = []
    fleet.client.ack = lambda mid, qos: acks.append(mid)
    return fleet, acks


def put(fleet: Fleet, mid: int, edge: str, data: bytes) -> None:
    fleet._queue.put((fleet._session, mid, 1, f"spBv1.0/g/DDATA/{edge}/h0", data))


def stored(tmp_path) -> list[tuple]:
    con = sqlite3.connect(str(tmp_path / "fleet.db"))
    try:
        sql = "SELECT edge_node, node, rope, frame_seq, tension_kn FROM tension ORDER BY arrival"
        return con.execute(sql).fetchall()
    finally:
        con.close()


def stop(fleet: Fleet) -> None:
    fleet._stop.set()
    fleet._writer.join(10)
    fleet.historian.close()


def test_metrics_the_station_cannot_send_are_refused_and_the_rest_written(tmp_path, caplog):
    """The reviewer's probe: a node number past SQLite's INTEGER made every later batch fail
    and nothing was committed or acknowledged again, for any edge node."""
    fleet, acks = rig(tmp_path)
    with caplog.at_level(logging.WARNING, logger="ropemon.station.mqtt.fleet"):
        put(fleet, 1, "bad-edge", ddata(10**20, 1, 1))              # node number
        put(fleet, 2, "good-edge", ddata(1, 2, 2))
        put(fleet, 3, "bad-edge", ddata(1, 3, 2**63))               # frame_seq past INTEGER
        put(fleet, 4, "bad-edge", ddata(1, 4, 3, tension=float("nan")))
        put(fleet, 5, "bad-edge", ddata(1, 5, 4, tension=float("inf")))
        put(fleet, 6, "bad-edge", ddata(1, 6, 5, rope=0))            # ropes count from 1
        put(fleet, 7, "bad-edge", ddata(256, 7, 6))
        put(fleet, 8, "bad-edge", ddata("1" * 5000, 8, 7))          # int() of it would raise
        put(fleet, 9, "bad-edge", ddata(1, 9, 8, ts=2**63 + 5))     # timestamp past INTEGER
        put(fleet, 10, "good-edge", ddata(2, 10, 9, tension=None))   # null: written, as documented
        fleet._writer.start()
        wait(lambda: acks == list(range(1, 11)), 5, "every message acknowledged")
    assert fleet.error is None
    assert stored(tmp_path) == [("good-edge", 1, 1, 2, 12.5), ("good-edge", 2, 1, 9, None)]
    # node 10**20: its frame_seq and tension; 2**63: the seq and its node's tension; then one each,
    # node 256 two, "1"*5000 two
    assert fleet.stats["refused"] == 2 + 2 + 1 + 1 + 1 + 2 + 2 + 1
    assert fleet.stats["refused_messages"] == 0
    assert "bad-edge" in caplog.text and "not written" in caplog.text
    assert fleet.stats["refused_by_reason"] == {"node or rope": 7, "frame_seq": 2, "tension": 2, "timestamp": 1}
    lines = [r.getMessage() for r in caplog.records if "not written" in r.getMessage()]
    assert len(lines) == 4                                            # rate-limited: the first of each reason
    assert all(f"({why})" in "".join(lines) for why in fleet.stats["refused_by_reason"])
    put(fleet, 11, "good-edge", ddata(1, 11, 10))
    wait(lambda: acks[-1:] == [11], 5, "a later message acknowledged")
    assert stored(tmp_path)[-1] == ("good-edge", 1, 1, 10, 12.5)
    stop(fleet)


class PickyHistorian(Historian):
    """Refuses, as a database would, any row of frame_seq 666 (a value the checks let through);
    cannot be written at all while `down`."""

    down = False

    def write(self, rows, hold=(), unhold=()):
        if self.down:
            raise sqlite3.OperationalError("database or disk is full")
        if any(r[7] == 666 for r in rows):
            raise OverflowError("Python int too large to convert to SQLite INTEGER")
        return super().write(rows, hold, unhold)


def test_a_message_the_historian_refuses_is_set_aside_and_the_rest_committed_in_order(tmp_path, caplog):
    h = PickyHistorian(tmp_path / "fleet.db")
    fleet, acks = rig(tmp_path, h)
    for k, seq in enumerate([1, 2, 666, 3, 4], start=1):
        put(fleet, k, "edge", ddata(1, k, seq))
    with caplog.at_level(logging.WARNING, logger="ropemon.station.mqtt.fleet"):
        fleet._writer.start()             # the five are one batch
        wait(lambda: acks == [1, 2, 3, 4, 5], 5, "all acknowledged, the refused one too")
    assert [r[3] for r in stored(tmp_path)] == [1, 2, 3, 4]
    assert fleet.stats["refused_messages"] == 1 and fleet.error is None
    assert "the historian refused it" in caplog.text and "spBv1.0/g/DDATA/edge/h0" in caplog.text
    stop(fleet)


def test_a_historian_that_cannot_be_written_keeps_everything_and_retries(tmp_path):
    h = PickyHistorian(tmp_path / "fleet.db")
    h.down = True
    fleet, acks = rig(tmp_path, h)
    put(fleet, 1, "edge", ddata(1, 1, 1))
    put(fleet, 2, "edge", ddata(1, 2, 2))
    fleet._writer.start()
    wait(lambda: fleet.error is not None, 5, "the write failing")
    time.sleep(1.5)                       # retried, still failing: nothing acknowledged nor dropped
    assert acks == [] and fleet.stats["refused_messages"] == 0 and "disk is full" in fleet.error
    h.down = False
    wait(lambda: acks == [1, 2], 5, "acknowledged once written")
    assert [r[3] for r in stored(tmp_path)] == [1, 2] and fleet.error is None
    stop(fleet)


def test_a_historian_made_before_the_positions_gets_the_column_and_keeps_its_rows(tmp_path):
    db = tmp_path / "old.db"
    con = sqlite3.connect(str(db))
    con.executescript("""
CREATE TABLE tension (
    group_id TEXT NOT NULL, edge_node TEXT NOT NULL, device TEXT NOT NULL, node INTEGER NOT NULL,
    rope INTEGER NOT NULL, ts_ms INTEGER NOT NULL, tension_kn REAL, frame_seq INTEGER NOT NULL,
    historical INTEGER NOT NULL, arrival INTEGER NOT NULL,
    PRIMARY KEY (group_id, edge_node, device, node, frame_seq, rope));
INSERT INTO tension VALUES ('mine', 'edge', 'h0', 1, 1, 1000, 50.0, 1, 0, 1);
""")
    con.close()
    h = Historian(db)
    h.write([("mine", "edge", "h0", 1, 1, 2000, 51.0, 2, False, -12.5),
             ("mine", "edge", "h0", 1, 2, 2000, 52.0, 2, False)])       # a row without a position
    got = h.conn.execute("SELECT frame_seq, rope, tension_kn, position_mm, arrival FROM tension "
                         "ORDER BY arrival").fetchall()
    h.close()
    assert got == [(1, 1, 50.0, None, 1), (2, 1, 51.0, -12.5, 2), (2, 2, 52.0, None, 3)]


def test_a_position_that_is_not_a_finite_number_is_refused_and_its_tension_written(tmp_path):
    fleet, acks = rig(tmp_path)
    for mid, pos in ((1, -12.5), (2, float("nan")), (3, None)):
        p = sp.decode(ddata(1, mid, mid))
        sp.add_metric(p, "node1/rope1/position", sp.DOUBLE, pos, p.timestamp)
        put(fleet, mid, "edge", p.SerializeToString())
    fleet._writer.start()
    wait(lambda: acks == [1, 2, 3], 5, "every message acknowledged")
    got = fleet.historian.conn.execute("SELECT frame_seq, tension_kn, position_mm FROM tension ORDER BY arrival").fetchall()
    assert got == [(1, 12.5, -12.5), (2, 12.5, None), (3, 12.5, None)]
    assert fleet.stats["refused"] == 1
    stop(fleet)
