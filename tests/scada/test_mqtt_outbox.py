"""The MQTT face's outbox: fresh records go out from memory (the outbox is not read back),
acknowledged rows are deleted together and not sent again after a reconnection, and what
was committed but not acknowledged when the station died is sent by the next run."""
from __future__ import annotations

import socket
import threading
import time

import pytest

pytest.importorskip("paho.mqtt")

from ropemon.station import mqtt as face_mod  # noqa: E402
from ropemon.station.faces import start_faces  # noqa: E402
from ropemon.station.mqtt import sparkplug as sp  # noqa: E402
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
    stations = SimpleNamespace(hoists=hoists, config=SimpleNamespace(data_dir=None))
    face = face_mod.MqttFace(stations, face_mod.parse_table({"group_id": "g", "edge_node_id": "e"}, tmp_path))
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


class CutProxy:
    """A TCP proxy between the station and Mosquitto that reads the MQTT packets going both ways
    and, once armed, cuts the connection at the next QoS 1 DDATA: `at = "publish"`: that PUBLISH
    is swallowed and the connection closed (the broker never had it); `at = "puback"`: it is
    forwarded, and the connection closed when the broker's PUBACK for it comes back, which is not
    forwarded (the broker had it, the station never hears so). Later connections pass untouched."""

    def __init__(self, broker_port: int) -> None:
        self.broker_port = broker_port
        self.at: str | None = None
        self.cut = threading.Event()
        self.cut_payload: bytes | None = None     # the DDATA the cut fell on
        self._pid: int | None = None              # its packet id (at = "puback")
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        threading.Thread(target=self._accept, daemon=True).start()

    def arm(self, at: str) -> None:
        self.at = at

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            broker = socket.create_connection(("127.0.0.1", self.broker_port))
            pair = (client, broker)
            threading.Thread(target=self._pump, args=(client, broker, pair, True), daemon=True).start()
            threading.Thread(target=self._pump, args=(broker, client, pair, False), daemon=True).start()

    @staticmethod
    def _packet(src: socket.socket) -> tuple[bytes, int, bytes] | None:
        """One MQTT packet: (the whole of it, its first byte, its body after the remaining length), None at the end."""
        def read(n: int) -> bytes | None:
            buf = b""
            while len(buf) < n:
                got = src.recv(n - len(buf))
                if not got:
                    return None
                buf += got
            return buf
        head = read(1)
        if head is None:
            return None
        length, shift, raw = 0, 0, b""
        while True:
            b = read(1)
            if b is None:
                return None
            raw += b
            length |= (b[0] & 0x7F) << shift
            shift += 7
            if not b[0] & 0x80:
                break
        body = read(length) if length else b""
        return None if body is None else head + raw + body, head[0], body

    def _close(self, pair) -> None:
        for s in pair:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()
        self.cut.set()

    def _pump(self, src, dst, pair, up: bool) -> None:
        try:
            while True:
                got = self._packet(src)
                if got is None:
                    break
                whole, first, body = got
                if up and self.at and first >> 4 == 3 and (first >> 1) & 3 == 1:      # a QoS 1 PUBLISH
                    n = int.from_bytes(body[:2], "big")
                    if "/DDATA/" in body[2:2 + n].decode():
                        self.cut_payload = body[2 + n + 2:]
                        if self.at == "publish":
                            self.at = None
                            self._close(pair)                 # swallowed: the broker never had it
                            return
                        self._pid, self.at = int.from_bytes(body[2 + n:2 + n + 2], "big"), None
                if not up and first >> 4 == 4 and self._pid is not None and int.from_bytes(body[:2], "big") == self._pid:
                    self._pid = None
                    self._close(pair)                         # the PUBACK is not forwarded
                    return
                dst.sendall(whole)
        except OSError:
            pass
        for s in pair:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def close(self) -> None:
        self.listener.close()


@pytest.mark.parametrize("at", ["publish", "puback"])
def test_a_ddata_cut_off_before_its_puback_is_sent_again_after_the_reconnection(tmp_path, broker, at):
    """The connection is cut between a DDATA's PUBLISH and its PUBACK (before the broker had it,
    or after, the PUBACK lost): its row stays in the outbox and goes out again, historical, after
    the reconnection; no frame is lost. (A face that took a row as sent when it was published, not
    when it was acknowledged, loses the first kind and does not send the second again.)"""
    proxy = CutProxy(broker.port)
    spy = Spy(broker.port)
    rig = Rig(tmp_path, 1, mqtt_table(proxy.port))
    (face,) = start_faces(rig.stations, rig.file)
    alias = face.alias["h0"]["node1/frame_seq"]
    try:
        wait(lambda: face.connected and face.sessions == 1 and spy.kinds("DBIRTH"), what="birth")
        for _ in range(5):
            rig.feed("h0", (5000 + rig.seq["h0"], 5000, 4900, 5100))
        wait(lambda: len(spy.kinds("DDATA")) == 5 and face.outbox.rows == 0, what="5 DDATA through, their rows gone")
        proxy.arm(at)
        for _ in range(5):
            rig.feed("h0", (5000 + rig.seq["h0"], 5000, 4900, 5100))
        wait(proxy.cut.is_set, what="the cut")
        cut_seq = next(sp.metric_value(m) for m in sp.decode(proxy.cut_payload).metrics if m.alias == alias)
        assert cut_seq == 6
        wait(lambda: face.connected and face.sessions == 2, what="connected again")
        for _ in range(5):
            rig.feed("h0", (5000 + rig.seq["h0"], 5000, 4900, 5100))
        wait(lambda: {metric(p, "node1/frame_seq") for _, p in spy.kinds("DDATA")} >= set(range(1, 16)), 10,
             "every frame at the broker")
        wait(lambda: face.outbox.rows == 0 and not face._inflight, 10, "every row acknowledged and deleted")
    finally:
        face.stop()
        rig.close()
        proxy.close()
    time.sleep(0.2)
    spy.close()
    got = [(metric(p, "node1/frame_seq"), all(m.is_historical for m in p.metrics)) for _, p in spy.kinds("DDATA")]
    seqs = [s for s, _ in got]
    assert sorted(set(seqs)) == list(range(1, 16))                 # none lost
    assert seqs[:5] == [1, 2, 3, 4, 5]
    if at == "puback":                                             # the broker had it: at least once, twice here
        assert seqs.count(6) == 2
    else:
        assert seqs.count(6) == 1
    assert (6, True) in got                                        # sent again after the reconnection, historical
