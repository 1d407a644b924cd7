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


class _Sent:
    def __init__(self, mid: int) -> None:
        self.mid, self.rc = mid, 0

    def is_published(self) -> bool:
        return True


class _NoAckClient:
    """A paho client that takes every publish and acknowledges none (the test does)."""

    def __init__(self) -> None:
        self.mid, self.sent = 0, []

    def publish(self, topic, payload, qos=0, retain=False):
        self.mid += 1
        self.sent.append((topic, payload))
        return _Sent(self.mid)

    def loop(self, timeout=0):
        return 0

    def disconnect(self):
        pass

    def socket(self):
        return None


def test_a_rebirth_sends_a_quiet_hoists_rows_still_to_publish_before_its_ddeath(tmp_path, monkeypatch):
    """A host's rebirth while the publisher is behind (MAX_INFLIGHT unacknowledged) and a hoist's
    newest record is its death: the hoist is born again for its live rows still to send, which
    go out, then its DDEATH (none deleted unsent); a hoist whose DDEATH was already out and has
    only a dropped alarm row still to send is not born."""
    from types import SimpleNamespace

    from ropemon.station.mqtt import sparkplug as sp

    fake = _NoAckClient()

    def connect(self):
        self.bdseq = (self.bdseq + 1) % 256
        self._client, self.connected, self.births, self.seq = fake, True, False, 0
        return True

    monkeypatch.setattr(face_mod.MqttFace, "_connect", connect)
    monkeypatch.setattr(face_mod.MqttFace, "_poll", lambda self, timeout=0.0, force=False: None)
    hoists = {h: SimpleNamespace(id=h, keys={1: None}) for h in ("h0", "h1")}
    stations = SimpleNamespace(hoists=hoists, file=SimpleNamespace(data_dir=None))
    face = face_mod.MqttFace(stations, face_mod.Settings({"group_id": "g", "edge_node_id": "e"}, tmp_path, "s"))
    n = 500
    face.start()
    try:
        wait(lambda: face.births, 5, "the session's births")
        face.queue.put(("h1", 900, {face_mod.DEVICE: "death"}))            # h1 quiet: its DDEATH goes out now
        wait(lambda: any("/DDEATH/" in t for t, _ in fake.sent), 5, "h1's DDEATH")
        for i in range(n):
            face.queue.put(("h0", 1000 + i, {"node1/frame_seq": i}))
        face.queue.put(("h1", 1600, {"alarms/present": 1}))               # a dead hoist's alarm row: dropped
        face.queue.put(("h0", 1700, {face_mod.DEVICE: "death"}))           # h0 goes quiet
        wait(lambda: face.outbox.rows == n + 3 and len(face._inflight) == face_mod.MAX_INFLIGHT, 5,
             "the publisher behind, MAX_INFLIGHT in flight")
        before = len(fake.sent)
        face._rebirth.set()                                                 # NCMD Node Control/Rebirth
        wait(lambda: any("/NBIRTH/" in t for t, _ in fake.sent[before:]), 5, "the rebirth")
        acked = 0

        def ack_all() -> bool:
            nonlocal acked
            face._acked.extend(range(acked + 1, fake.mid + 1))              # the broker acknowledges
            acked = fake.mid
            return face.outbox.rows == 0 and not face._inflight
        wait(ack_all, 10, "every row acknowledged or dropped")
        sent = list(fake.sent)                                              # (the stop adds its NDEATH)
    finally:
        face.stop()
    kinds = [(t.split("/")[2], t.split("/")[4:]) for t, _ in sent]        # (type, [device])
    seqs = [sp.metric_value(m) for t, p in sent if "/DDATA/" in t for m in sp.decode(p).metrics]
    assert seqs == list(range(n))                                           # every committed row, in order, once
    after = kinds[before:]
    nbirth = after.index(("NBIRTH", []))
    assert [k for k in after[nbirth:] if k[0] != "DDATA"] == [("NBIRTH", []), ("DBIRTH", ["h0"]),
                                                               ("DDEATH", ["h0"])]
    assert after[-1] == ("DDEATH", ["h0"])                                   # after all of h0's data
    assert not any(k[1] == ["h1"] for k in after[nbirth:])                   # h1 stays dead: no DBIRTH, no DDATA
