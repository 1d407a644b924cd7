"""The MQTT face's outbox: fresh records go out from memory (the outbox is not read back),
acknowledged rows are deleted together and not sent again after a reconnection, and what
was committed but not acknowledged when the station died is sent by the next run."""
from __future__ import annotations

import socket
import time

import pytest

pytest.importorskip("paho.mqtt")

from ropemon.station import mqtt as face_mod  # noqa: E402
from ropemon.station.faces import start_faces  # noqa: E402
from ropemon.station.mqtt.outbox import Outbox  # noqa: E402
from scada_rig import Rig, free_port, wait  # noqa: E402
from test_mqtt import Spy, metric, mqtt_table  # noqa: E402


def test_fresh_records_go_out_from_memory_and_acknowledged_rows_are_not_sent_again(tmp_path, broker, monkeypatch):
    monkeypatch.setattr(face_mod, "DELETE_S", 3600.0)       # acknowledged rows wait for their delete ...
    monkeypatch.setattr(face_mod, "DELETE_EVERY", 10_000)   # ... until a reconnection or the stop
    read = []
    after = Outbox.after
    monkeypatch.setattr(Outbox, "after", lambda self, row_id, limit: read.extend(rows := after(self, row_id, limit))
                        or rows)
    spy = Spy(broker.port)
    rig = Rig(tmp_path, 1, mqtt_table(broker.port))
    (face,) = start_faces(rig.stations, rig.file)
    try:
        wait(lambda: face.connected and spy.kinds("DBIRTH"), what="birth")
        for _ in range(20):
            rig.feed("h0", (5000 + rig.seq["h0"], 5000, 4900, 5100))
        wait(lambda: face.sent == 20, what="20 DDATA acknowledged")
        assert read == []                                   # published from memory
        assert face.outbox.rows == 20                       # acknowledged, their delete pending
        face._client.socket().shutdown(socket.SHUT_RDWR)    # the connection dies
        wait(lambda: face.connected and face.sessions == 2, what="connected again")
        assert face.outbox.rows == 0                        # deleted before the outbox is read again
        for _ in range(5):
            rig.feed("h0", (5000 + rig.seq["h0"], 5000, 4900, 5100))
        wait(lambda: face.sent == 25, what="5 more DDATA")
    finally:
        face.stop()
        rig.close()
    time.sleep(0.3)
    spy.close()
    seqs = [metric(p, "node1/frame_seq") for _, p in spy.kinds("DDATA")]
    assert seqs == list(range(1, 26))                       # none sent twice
    assert Outbox(tmp_path / "data" / "mqtt-outbox.db", 1000).rows == 0   # the stop deleted the last ones


def test_a_row_committed_but_not_acknowledged_is_sent_by_the_next_run(tmp_path, broker):
    """The insert's commit is the durability point: a station stopped with rows in the outbox
    that no broker acknowledged sends them in its next run, historical."""
    rig = Rig(tmp_path, 1, mqtt_table(free_port()))         # nobody listens there: nothing is acknowledged
    (face,) = start_faces(rig.stations, rig.file)
    for _ in range(3):
        rig.feed("h0", (5000 + rig.seq["h0"], 5000, 4900, 5100))
    wait(lambda: face.outbox.rows == 3, what="3 rows committed")
    face.stop()
    rig.close()
    spy = Spy(broker.port)
    rig2 = Rig(tmp_path, 1, mqtt_table(broker.port))         # the same data_dir
    (face2,) = start_faces(rig2.stations, rig2.file)
    try:
        wait(lambda: len(spy.kinds("DDATA")) == 3, what="the 3 stored frames")
        wait(lambda: face2.outbox.rows == 0, what="acknowledged and deleted")
    finally:
        face2.stop()
        rig2.close()
        spy.close()
    data = [p for _, p in spy.kinds("DDATA")]
    assert [metric(p, "node1/frame_seq") for p in data] == [1, 2, 3]
    assert all(m.is_historical for p in data for m in p.metrics)
