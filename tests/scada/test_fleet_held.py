"""The fleet consumer's held DDATA (their aliases unknown: it missed the DBIRTH) are on disk
before they are acknowledged: a consumer killed before the births loses none, and writes each
once when the births come after its restart. The hold is bounded, its losses counted."""
from __future__ import annotations

import logging
import signal
import sqlite3
import subprocess
import sys
import threading
import time

import pytest

pytest.importorskip("paho.mqtt")

import paho.mqtt.client as paho  # noqa: E402

from ropemon.station.mqtt import fleet as fleet_mod  # noqa: E402
from ropemon.station.mqtt import sparkplug as sp  # noqa: E402
from ropemon.station.mqtt.fleet import Fleet, Historian  # noqa: E402
from scada_rig import wait  # noqa: E402

GROUP, EDGE = "mine", "shaft-9"
METRICS = [f"node1/rope{r}/tension" for r in range(1, 5)] + ["node1/frame_seq"]
ALIAS = {"h0": {n: k + 1 for k, n in enumerate(METRICS)}, "h1": {n: k + 11 for k, n in enumerate(METRICS)}}


def ddata(device: str, seq: int, frame_seq: int) -> bytes:
    p = sp.payload(seq)
    for r in range(1, 5):
        sp.add_metric(p, None, sp.DOUBLE, 50.0 + frame_seq + r / 10, 1_000 * frame_seq,
                      alias=ALIAS[device][f"node1/rope{r}/tension"])
    sp.add_metric(p, None, sp.UINT64, frame_seq, 1_000 * frame_seq, alias=ALIAS[device]["node1/frame_seq"])
    return p.SerializeToString()


def dbirth(device: str, seq: int) -> bytes:
    p = sp.payload(seq)
    for name in METRICS:
        sp.add_metric(p, name, sp.UINT64 if name.endswith("frame_seq") else sp.DOUBLE, None, 0,
                      alias=ALIAS[device][name])
    return p.SerializeToString()


def nbirth(bd: int) -> bytes:
    p = sp.payload(0)
    sp.add_metric(p, "bdSeq", sp.INT64, bd, p.timestamp)
    return p.SerializeToString()


class EdgeNode:
    """A hand-driven Sparkplug edge node: publishes what the test says, notes the NCMDs."""

    def __init__(self, port: int) -> None:
        self.ncmd = 0
        ready = threading.Event()
        c = self.c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="edge-by-hand")
        c.on_connect = lambda cl, *a: (cl.subscribe(sp.topic(GROUP, "NCMD", EDGE), qos=1), ready.set())
        c.on_message = lambda cl, u, m: setattr(self, "ncmd", self.ncmd + 1)
        c.connect("127.0.0.1", port)
        c.loop_start()
        assert ready.wait(5)
        time.sleep(0.2)

    def send(self, kind: str, device: str | None, data: bytes, qos: int = 1) -> None:
        self.c.publish(sp.topic(GROUP, kind, EDGE, device), data, qos=qos).wait_for_publish(5)

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()


def count(db, sql: str) -> int:
    con = sqlite3.connect(str(db))
    try:
        return con.execute(sql).fetchone()[0]
    except sqlite3.OperationalError:          # the consumer has not made its tables yet
        return -1
    finally:
        con.close()


def test_held_ddata_survive_a_killed_consumer_and_are_written_once_at_the_births(tmp_path, broker):
    db = tmp_path / "fleet.db"
    edge = EdgeNode(broker.port)
    cmd = [sys.executable, "-m", "ropemon.cli", "fleet", "--port", str(broker.port), "--group", GROUP,
           "--client-id", "fleet-held", "--db", str(db)]
    first = Fleet(Historian(db), port=broker.port, group=GROUP, client_id="fleet-held")
    first.start()                                         # the session and its subscription, kept by the broker
    assert first.connected.wait(10)
    time.sleep(0.3)
    first.stop()
    first.historian.close()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        seq = 0
        for k in range(1, 6):                             # the consumer never saw this edge node's births
            for device in ("h0", "h1"):
                seq += 1
                edge.send("DDATA", device, ddata(device, seq, k))
        wait(lambda: count(db, "SELECT COUNT(*) FROM held") == 10, 20, "the 10 DDATA held on disk")
        wait(lambda: edge.ncmd == 1, 10, "the rebirth asked for")
        time.sleep(0.5)                                   # the PUBACKs follow the commit
    finally:
        proc.send_signal(signal.SIGKILL)                  # dies before any DBIRTH
        proc.wait(10)
    assert count(db, "SELECT COUNT(*) FROM tension") == 0

    fleet = Fleet(Historian(db), port=broker.port, group=GROUP, client_id="fleet-held")
    assert fleet.stats["held_loaded"] == 10 and fleet.held_count == 10
    fleet.start()
    try:
        assert fleet.connected.wait(10)
        wait(lambda: edge.ncmd == 2, 10, "a rebirth asked for at start, for the held DDATA")
        time.sleep(0.5)
        with fleet.lock:
            assert fleet.stats["held"] == 0                # acknowledged before the kill: not delivered again
        edge.send("NBIRTH", None, nbirth(3), qos=0)
        edge.send("DBIRTH", "h0", dbirth("h0", 1), qos=0)
        wait(lambda: count(db, "SELECT COUNT(*) FROM tension") == 5 * 4, 10, "h0's held rows written")
        assert count(db, "SELECT COUNT(*) FROM held") == 5                # h1's still held
        edge.send("DBIRTH", "h1", dbirth("h1", 2), qos=0)
        edge.send("DDATA", "h1", ddata("h1", 3, 6))                       # live, named at once
        wait(lambda: count(db, "SELECT COUNT(*) FROM tension") == 11 * 4, 10, "every row")
        assert count(db, "SELECT COUNT(*) FROM held") == 0
    finally:
        fleet.stop()
        fleet.historian.close()
        edge.close()
    con = sqlite3.connect(str(db))
    got = con.execute("SELECT device, frame_seq, rope, tension_kn FROM tension ORDER BY device, frame_seq, rope").fetchall()
    con.close()
    want = [(d, k, r, 50.0 + k + r / 10) for d, n in (("h0", 5), ("h1", 6)) for k in range(1, n + 1)
            for r in range(1, 5)]
    assert got == want                                     # each exactly once

    again = Fleet(Historian(db), port=broker.port, group=GROUP, client_id="fleet-held")   # nothing left held
    assert again.stats["held_loaded"] == 0
    again.historian.close()


def test_the_hold_is_bounded_and_its_losses_counted_and_logged(tmp_path, monkeypatch, caplog):
    """Past HOLD per hoist (or HOLD_TOTAL in all) the oldest held DDATA is dropped: counted,
    logged, deleted from the held table; the rest are written when the DBIRTH comes."""
    monkeypatch.setattr(fleet_mod, "HOLD", 3)
    monkeypatch.setattr(fleet_mod, "HOLD_TOTAL", 5)
    db = tmp_path / "fleet.db"
    fleet = Fleet(Historian(db), port=1, group=GROUP)       # never connected: the writer is driven by hand

    def take(topic, data):
        rows = fleet.rows_of(topic, data)
        fleet.historian.write(rows, fleet._hold_new, fleet._hold_gone)
        fleet._hold_new, fleet._hold_gone = [], []

    with caplog.at_level(logging.WARNING, logger="ropemon.station.mqtt.fleet"):
        for k in range(1, 6):
            take(sp.topic(GROUP, "DDATA", EDGE, "h0"), ddata("h0", k, k))
        for k in range(1, 4):
            take(sp.topic(GROUP, "DDATA", EDGE, "h1"), ddata("h1", 5 + k, k))
    # h0: 5 held, past 3 its two oldest dropped; h1: 3 more make 6 in all, past 5 h0's oldest left goes
    assert fleet.stats["held"] == 8 and fleet.stats["dropped"] == 3 and fleet.held_count == 5
    assert count(db, "SELECT COUNT(*) FROM held") == 5
    assert "DDATA dropped unwritten" in caplog.text and f"{GROUP}/{EDGE}/h0" in caplog.text
    take(sp.topic(GROUP, "DBIRTH", EDGE, "h0"), dbirth("h0", 9))
    take(sp.topic(GROUP, "DBIRTH", EDGE, "h1"), dbirth("h1", 10))
    con = sqlite3.connect(str(db))
    got = con.execute("SELECT device, frame_seq FROM tension WHERE rope = 1 ORDER BY device, frame_seq").fetchall()
    con.close()
    assert got == [("h0", 4), ("h0", 5), ("h1", 1), ("h1", 2), ("h1", 3)]
    assert count(db, "SELECT COUNT(*) FROM held") == 0 and fleet.held_count == 0
    fleet.historian.close()
