"""The MQTT Sparkplug B face against a real Mosquitto: births, data, deaths, bdSeq and seq,
store-and-forward across a broker kill, and the fleet consumer's historian."""
from __future__ import annotations

import socket
import threading
import time

import pytest

pytest.importorskip("paho.mqtt")

import paho.mqtt.client as paho  # noqa: E402

from ropemon.station.faces import start_faces  # noqa: E402
from ropemon.station.mqtt import sparkplug as sp  # noqa: E402
from ropemon.station.mqtt.fleet import Fleet, Historian  # noqa: E402
from ropemon.station.stationfile import StationConfigError  # noqa: E402
from scada_rig import Rig, wait  # noqa: E402


class Spy:
    """Every Sparkplug message on the broker, decoded, in arrival order; a DDATA's metrics
    (sent by alias only) given their names from the device's DBIRTH, as a host does."""

    def __init__(self, port: int) -> None:
        self.msgs: list[tuple[str, object]] = []
        self.names: dict[str, dict[int, str]] = {}      # DBIRTH topic's device -> alias -> name
        self.ready = threading.Event()
        c = self.c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="spy")
        c.on_connect = lambda cl, *a: (cl.subscribe("spBv1.0/#", qos=1), self.ready.set())
        c.on_message = lambda cl, u, m: self._on_message(m.topic, m.payload)
        c.connect("127.0.0.1", port)
        c.loop_start()
        assert self.ready.wait(5)
        time.sleep(0.2)

    def _on_message(self, topic: str, data: bytes) -> None:
        p = sp.decode(data)
        parts = topic.split("/")
        if len(parts) == 5 and parts[2] == "DBIRTH":
            self.names[parts[4]] = {m.alias: m.name for m in p.metrics}
        elif len(parts) == 5 and parts[2] == "DDATA":
            for m in p.metrics:
                assert not m.name, f"DDATA metric {m.name} sent by name, not by its alias"
                m.name = self.names[parts[4]][m.alias]
        self.msgs.append((topic, p))

    def kinds(self, kind: str) -> list:
        return [(t, p) for t, p in list(self.msgs) if t.split("/")[2] == kind]

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()


def mqtt_table(port: int, edge: str = "shaft-2", extra: str = "") -> str:
    return f'[mqtt]\nport = {port}\ngroup_id = "mine"\nedge_node_id = "{edge}"\n{extra}'


def metric(p, name):
    return next(sp.metric_value(m) for m in p.metrics if m.name == name)


def test_birth_data_and_death_with_bdseq_and_seq(tmp_path, broker):
    spy = Spy(broker.port)
    rig = Rig(tmp_path, 2, mqtt_table(broker.port))
    (face,) = start_faces(rig.stations, rig.file)
    try:
        wait(lambda: len(spy.kinds("DBIRTH")) == 2, what="births")
        (nb_topic, nb), = spy.kinds("NBIRTH")
        assert nb_topic == "spBv1.0/mine/NBIRTH/shaft-2" and nb.seq == 0
        bd = metric(nb, "bdSeq")
        assert metric(nb, "Node Control/Rebirth") is False
        (t0, db0), (t1, db1) = spy.kinds("DBIRTH")
        assert (t0, t1) == ("spBv1.0/mine/DBIRTH/shaft-2/h0", "spBv1.0/mine/DBIRTH/shaft-2/h1")
        units = {m.name: sp.unit_of(m) for m in db0.metrics}
        assert units["node1/rope1/tension"] == "kN" and units["node1/depth"] == "m" and units["vouched"] is None
        assert all(m.is_null for m in db0.metrics if m.name.startswith("node1/"))   # nothing heard yet
        for k in range(150):                                  # 300 DDATA: seq wraps past 255
            rig.feed("h0", (5000 + k, 5000, 5000, 5000), depth_mm=1000 * k)
            rig.feed("h1", (6000, 6000, None, 6000))
        wait(lambda: len(spy.kinds("DDATA")) >= 300, what="300 DDATA")
        data = [p for t, p in spy.kinds("DDATA") if t.endswith("/h0")]
        assert [metric(p, "node1/frame_seq") for p in data] == list(range(1, 151))
        assert [metric(p, "node1/rope1/tension") for p in data[:3]] == [50.0, 50.01, 50.02]
        assert metric(data[2], "node1/depth") == 2.0
        assert not any(m.is_historical for p in data for m in p.metrics)
        h1 = [p for t, p in spy.kinds("DDATA") if t.endswith("/h1")]
        assert metric(h1[0], "node1/rope3/tension") is None and metric(h1[0], "node1/sum") is None
        seqs = [p.seq for t, p in spy.msgs if t.split("/")[2] in ("NBIRTH", "DBIRTH", "DDATA")]
        assert seqs == [k % 256 for k in range(len(seqs))] and len(seqs) > 256
        # the connection dies without DISCONNECT: the broker publishes the will, NDEATH with this bdSeq;
        # the face connects again with the next bdSeq and is born again
        face._client.socket().shutdown(socket.SHUT_RDWR)
        wait(lambda: len(spy.kinds("NDEATH")) == 1 and len(spy.kinds("NBIRTH")) == 2, what="will and rebirth")
        assert metric(spy.kinds("NDEATH")[0][1], "bdSeq") == bd
        nb2 = spy.kinds("NBIRTH")[1][1]
        assert metric(nb2, "bdSeq") == (bd + 1) % 256 and nb2.seq == 0
    finally:
        face.stop()
        rig.close()
    wait(lambda: len(spy.kinds("NDEATH")) == 2, what="NDEATH at a clean stop")
    assert metric(spy.kinds("NDEATH")[1][1], "bdSeq") == (bd + 1) % 256
    spy.close()


def test_report_by_exception_sends_what_moved_beyond_the_deadband(tmp_path, broker):
    spy = Spy(broker.port)
    rig = Rig(tmp_path, 1, mqtt_table(broker.port, extra='report = "exception"\ndeadband = { kN = 1.0, "%" = 5.0 }\n'))
    (face,) = start_faces(rig.stations, rig.file)
    try:
        wait(lambda: spy.kinds("DBIRTH"), what="birth")
        rig.feed("h0", (5000, 5000, 5000, 5000))
        rig.feed("h0", (5050, 5000, 5000, 5000))       # +0.5 kN: within the deadband
        rig.feed("h0", (5100, 5000, 5000, 5000))       # +1.0 kN from the last reported
        wait(lambda: len(spy.kinds("DDATA")) >= 2, what="DDATA")
        time.sleep(0.3)
        first, second = [p for _, p in spy.kinds("DDATA")]
        assert metric(first, "node1/rope1/tension") == 50.0 and metric(first, "node1/frame_seq") == 1
        names = {m.name for m in second.metrics}
        assert metric(second, "node1/rope1/tension") == 51.0 and metric(second, "node1/frame_seq") == 3
        assert "node1/rope2/tension" not in names                # unchanged: not sent
    finally:
        face.stop()
        rig.close()
        spy.close()


def test_a_bad_mqtt_table_is_refused_with_the_field(tmp_path):
    rig = Rig(tmp_path, 1, '[mqtt]\ngroup_id = "a/b"\nedge_node_id = "x"\n')
    try:
        with pytest.raises(StationConfigError, match="mqtt.group_id"):
            start_faces(rig.stations, rig.file)
    finally:
        rig.close()


def test_n_stations_arrive_complete_and_in_order_across_a_broker_kill(tmp_path, broker):
    """Three stations of two hoists each; the broker is killed (SIGKILL) and restarted while
    they go on: the fleet's historian ends with every rope of every frame, in order, the
    frames of the outage marked historical."""
    hist = Historian(tmp_path / "fleet.db")
    fleet = Fleet(hist, port=broker.port, group="mine", client_id="fleet-test")
    fleet.start()
    assert fleet.connected.wait(5)                        # subscribed: it hears the stations' births
    rigs, faces = [], []
    for i in range(3):
        d = tmp_path / f"station{i}"
        d.mkdir()
        rig = Rig(d, 2, mqtt_table(broker.port, edge=f"station-{i}"))
        rigs.append(rig)
        faces += start_faces(rig.stations, rig.file)

    def feed(n):
        for _ in range(n):
            for rig in rigs:
                for h in rig.ids:
                    rig.feed(h, (5000 + rig.seq[h], 5000, 4900, 5100))

    def rows():
        return hist.conn.execute("SELECT COUNT(*) FROM tension").fetchone()[0]

    try:
        # born, not only connected: a row queued before its session's births goes out historical
        wait(lambda: all(f.connected and f.sessions == 1 for f in faces), what="stations born")
        feed(40)                                          # phase A: live
        wait(lambda: rows() == 3 * 2 * 40 * 4, what="phase A in the historian")
        saved = broker.saved()        # a save finished (not only begun) keeps the consumer's session
        wait(lambda: broker.saved() != saved, what="the broker saving the consumer's session")
        broker.kill()
        wait(lambda: not any(f.connected for f in faces), what="stations see the broker gone")
        feed(60)                                          # phase B: the broker is down
        wait(lambda: all(f.outbox.rows >= 2 * 60 for f in faces), what="the outage's frames on disk")
        broker.start()
        wait(lambda: all(f.connected and f.sessions == 2 for f in faces), 30, "stations back")
        feed(30)                                          # phase C: live again
        wait(lambda: rows() == 3 * 2 * 130 * 4, 30, "every frame in the historian")
    finally:
        for f in faces:
            f.stop()
        for rig in rigs:
            rig.close()
        fleet.stop()
    db = hist.conn
    for i in range(3):
        for h in ("h0", "h1"):
            got = db.execute("SELECT frame_seq, rope, tension_kn, historical FROM tension "
                             "WHERE edge_node = ? AND device = ? ORDER BY arrival", (f"station-{i}", h)).fetchall()
            seqs = [s for s, r, _, _ in got if r == 1]
            assert seqs == list(range(1, 131))                        # complete and in order
            assert [t for s, r, t, _ in got if r == 1] == [(5000 + s - 1) / 100 for s in seqs]
            hist_flags = {s: bool(x) for s, r, _, x in got if r == 1}
            assert not any(hist_flags[s] for s in range(1, 41))      # phase A: live
            assert all(hist_flags[s] for s in range(41, 101))        # phase B: replayed, is_historical
            assert not any(hist_flags[s] for s in range(101, 131))   # phase C: live
    # births are QoS 0 (Sparkplug): those sent while the consumer was still away are not queued for it
    assert fleet.stats["births"] >= 3 and fleet.stats["historical"] >= 3 * 2 * 60 * 4
    hist.close()


def test_ropemon_serve_starts_the_modbus_and_mqtt_faces_and_stops_them_cleanly(tmp_path, broker):
    """The faces come up through `ropemon serve` (station/faces.py), as for the demo."""
    import signal
    import subprocess
    import sys

    from pymodbus.client import ModbusTcpClient

    from scada_rig import free_port, write_station
    spy = Spy(broker.port)
    port = free_port()
    path = write_station(tmp_path, 2, f"[modbus]\nport = {port}\n\n" + mqtt_table(broker.port))
    proc = subprocess.Popen([sys.executable, "-m", "ropemon.cli", "serve", str(path), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait(lambda: len(spy.kinds("DBIRTH")) == 2, 30, "births from ropemon serve")
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=3)
        wait(client.connect, 10, "the Modbus server")
        assert client.read_holding_registers(0, count=2).registers == [2, 2]   # map version 2, 2 hoists
        client.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "Modbus TCP on 127.0.0.1:" in err and "MQTT Sparkplug B to 127.0.0.1:" in err
    wait(lambda: spy.kinds("NDEATH"), 10, "NDEATH at the clean stop")
    spy.close()
