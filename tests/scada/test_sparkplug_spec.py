"""The MQTT face against the Sparkplug B specification, read back by Eclipse Tahu's payload
codec (npm sparkplug-payload, not ropemon's protobuf module): births with names, aliases,
datatypes and units; DDATA by alias; DDEATH when the station stops hearing a hoist and
DBIRTH when it hears it again; NDEATH; bdSeq and seq; the primary host's STATE; the fleet
consumer naming DDATA from the births and asking for a rebirth when it missed them."""
from __future__ import annotations

import base64
import json
import logging
import queue
import shutil
import subprocess
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

pytest.importorskip("paho.mqtt")

import paho.mqtt.client as paho  # noqa: E402

from ropemon.station.faces import start_faces  # noqa: E402
from ropemon.station.stationfile import StationConfigError  # noqa: E402
from scada_rig import Rig, wait  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TAHU = Path(__file__).with_name("tahu_decode.js")

# What a hoist with cage node 1 publishes (docs/integration.md), written out here rather than
# taken from ropemon's sparkplug module: name -> (Tahu's datatype name, engUnit)
NODE1 = {**{f"node1/rope{r}/tension": ("Double", "kN") for r in range(1, 5)},
         **{f"node1/rope{r}/deviation": ("Double", "%") for r in range(1, 5)},
         "node1/sum": ("Double", "kN"), "node1/depth": ("Double", "m"), "node1/speed": ("Double", "m/s"),
         "node1/battery": ("Double", "V"), "node1/oil_temperature": ("Double", "degC"),
         "node1/status": ("UInt32", None), "node1/frame_seq": ("UInt64", None),
         **{f"node1/rope{r}/position": ("Double", "mm") for r in range(1, 5)},
         **{f"node1/rope{r}/near_{end}_end": ("Boolean", None) for r in range(1, 5) for end in ("retracted", "extended")},
         "node1/hidden_imbalance": ("Double", "%"), "node1/standing_status": ("String", None),
         "alarms/present": ("UInt32", None), "alarms/unacknowledged": ("UInt32", None),
         "alarms/equalizer_present": ("UInt32", None), "alarms/equalizer_unacknowledged": ("UInt32", None),
         "vouched": ("Boolean", None)}
ALARM_METRICS = {"alarms/present", "alarms/unacknowledged", "alarms/equalizer_present",
                 "alarms/equalizer_unacknowledged", "vouched"}


def tahu(payloads: list[bytes]) -> list[dict]:
    """Decode with Eclipse Tahu's JavaScript codec (64-bit integers come back as strings)."""
    node = shutil.which("node")
    if node is None or not (ROOT / "node_modules" / "sparkplug-payload").exists():
        pytest.fail("node and node_modules/sparkplug-payload are needed: `make test` installs them (npm ci)")
    out = subprocess.run([node, str(TAHU)], input=json.dumps([base64.b64encode(p).decode() for p in payloads]),
                         capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


class RawSpy:
    """Every message under spBv1.0/ as sent (topic, payload bytes, QoS, retain), in arrival order."""

    def __init__(self, port: int) -> None:
        self.msgs: list[tuple[str, bytes, int, bool]] = []
        self.ready = threading.Event()
        c = self.c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=f"raw-spy-{port}")
        c.on_connect = lambda cl, *a: (cl.subscribe("spBv1.0/#", qos=1), self.ready.set())
        c.on_message = lambda cl, u, m: self.msgs.append((m.topic, m.payload, m.qos, m.retain))
        c.connect("127.0.0.1", port)
        c.loop_start()
        assert self.ready.wait(5)
        time.sleep(0.2)

    def kinds(self, kind: str, device: str | None = None) -> list[tuple[str, bytes, int, bool]]:
        return [m for m in list(self.msgs) if m[0].split("/")[2] == kind
                and (device is None or m[0].endswith(f"/{device}"))]

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()


def mqtt_table(port: int, edge: str = "shaft-2", extra: str = "") -> str:
    return f'[mqtt]\nport = {port}\ngroup_id = "mine"\nedge_node_id = "{edge}"\n{extra}'


def by_name(p: dict) -> dict[str, dict]:
    return {m["name"]: m for m in p["metrics"]}


def test_tahu_reads_births_data_device_death_and_node_death(tmp_path, broker):
    spy = RawSpy(broker.port)
    t0 = int(time.time() * 1000)
    rig = Rig(tmp_path, 2, mqtt_table(broker.port))          # silent_s = 2.0
    (face,) = start_faces(rig.stations, rig.file)
    try:
        wait(lambda: len(spy.kinds("DBIRTH")) == 2, what="births")
        rig.step()
        for k in range(3):
            rig.feed("h0", (5000 + k, 5100, 4900, 5000), depth_mm=1000 * k)
        rig.feed("h1", (6000, 6000, None, 6000))
        wait(lambda: len(spy.kinds("DDATA")) >= 4, what="DDATA")
        for _ in range(12):                                   # 3 s: h1 silent past silent_s, h0 heard
            rig.feed("h0", (5000 + rig.seq["h0"], 5100, 4900, 5000))
            rig.step()
        wait(lambda: spy.kinds("DDEATH"), what="DDEATH of h1")
        time.sleep(0.3)
        assert [t for t, *_ in spy.kinds("DDEATH")] == ["spBv1.0/mine/DDEATH/shaft-2/h1"]
        rig.feed("h1", (6100, 6000, None, 6000))             # heard again: born again, then its data
        wait(lambda: len(spy.kinds("DBIRTH", "h1")) == 2, what="DBIRTH of h1 again")
        n = len(spy.kinds("DDATA", "h1"))
        wait(lambda: len(spy.kinds("DDATA", "h1")) > n, what="h1's DDATA after its rebirth")
    finally:
        face.stop()
        rig.close()
    wait(lambda: spy.kinds("NDEATH"), 10, "NDEATH at a clean stop")
    t1 = int(time.time() * 1000)
    spy.close()

    msgs = list(spy.msgs)
    decoded = tahu([m[1] for m in msgs])
    kinds = [t.split("/")[2] for t, *_ in msgs]
    assert kinds[:3] == ["NBIRTH", "DBIRTH", "DBIRTH"] and kinds[-1] == "NDEATH"
    for (topic, _, qos, retain), p in zip(msgs, decoded):
        assert not retain
        assert t0 <= int(p["timestamp"]) <= t1                # ms since the epoch, UTC: when sent
        for m in p.get("metrics", []):
            assert t0 <= int(m["timestamp"]) <= int(p["timestamp"])   # when the station received it
        if topic.split("/")[2] in ("NBIRTH", "DBIRTH", "DDEATH"):
            assert qos == 0                                   # the specification's QoS for these
    # seq: NBIRTH 0, then one more per message of the session, NDEATH without one
    seqs = [int(p["seq"]) for p, k in zip(decoded, kinds) if k != "NDEATH"]
    assert seqs == list(range(len(seqs)))
    assert "seq" not in decoded[-1]

    nb = by_name(decoded[0])
    assert nb["bdSeq"]["type"] == "Int64" and nb["Node Control/Rebirth"] == {
        "name": "Node Control/Rebirth", "type": "Boolean", "value": False, "timestamp": nb["bdSeq"]["timestamp"]}
    bd = nb["bdSeq"]["value"]
    death = decoded[-1]
    assert [(m["name"], m["type"], m["value"]) for m in death["metrics"]] == [("bdSeq", "Int64", bd)]

    # DBIRTH: every metric by name, alias, datatype and unit; aliases unique in the edge node
    births = [(t.split("/")[4], p) for (t, *_), p in zip(msgs, decoded) if "/DBIRTH/" in t]
    assert [d for d, _ in births] == ["h0", "h1", "h1"]
    aliases: dict[str, dict[str, str]] = {}
    for device, p in births[:2]:
        got = {m["name"]: (m["type"], m.get("properties", {}).get("engUnit", {}).get("value")) for m in p["metrics"]}
        assert got == NODE1
        for m in p["metrics"]:
            if "engUnit" in m.get("properties", {}):
                assert m["properties"]["engUnit"]["type"] == "String"
        aliases[device] = {m["alias"]: m["name"] for m in p["metrics"]}
        assert len(aliases[device]) == len(NODE1)
    assert not set(aliases["h0"]) & set(aliases["h1"])
    assert all(m["value"] is None for m in births[0][1]["metrics"] if m["name"].startswith("node1/"))
    assert {m["alias"]: m["name"] for m in births[2][1]["metrics"]} == aliases["h1"]   # the same aliases

    # DDATA: by alias only, each value that of its frame (the others: the alarm bits changing)
    data: dict[str, list[dict]] = {"h0": [], "h1": []}
    for (t, *_), p in zip(msgs, decoded):
        if "/DDATA/" in t:
            device = t.split("/")[4]
            assert all("name" not in m and m["alias"] in aliases[device] for m in p["metrics"])
            d = {aliases[device][m["alias"]]: m for m in p["metrics"]}
            if "node1/frame_seq" in d:
                data[device].append(d)
            else:
                assert set(d) <= ALARM_METRICS | {"node1/standing_status"}   # or the standing status's text
    h0 = data["h0"]
    assert [int(d["node1/frame_seq"]["value"]) for d in h0] == list(range(1, len(h0) + 1)) and len(h0) == 15
    for k, d in enumerate(h0[:3]):
        assert d["node1/rope1/tension"]["value"] == (5000 + k) / 100 and d["node1/rope1/tension"]["type"] == "Double"
        assert d["node1/rope2/tension"]["value"] == 51.0 and d["node1/depth"]["value"] == float(k)
        assert d["node1/battery"]["value"] == 12.0 and d["node1/status"]["type"] == "UInt32"
        assert not d["node1/rope1/tension"].get("isHistorical", False)
    h1 = data["h1"]
    assert [int(d["node1/frame_seq"]["value"]) for d in h1] == [1, 2]
    assert h1[0]["node1/rope3/tension"]["value"] is None and h1[0]["node1/sum"]["value"] is None
    assert h1[1]["node1/rope1/tension"]["value"] == 61.0
    # h1: DDATA, DDEATH, DBIRTH, DDATA, and nothing of h1 between its death and its birth
    h1_kinds = [k for (t, *_), k in zip(msgs, kinds) if t.endswith("/h1")]
    h1_kinds = [k for i, k in enumerate(h1_kinds) if i == 0 or k != h1_kinds[i - 1]]
    assert h1_kinds == ["DBIRTH", "DDATA", "DDEATH", "DBIRTH", "DDATA"]
    ddeath = next(p for (t, *_), p in zip(msgs, decoded) if "/DDEATH/" in t)
    assert not ddeath.get("metrics")


def test_the_hoist_is_declared_dead_when_every_receiver_is_down_and_born_at_its_next_frame():
    """SparkplugValues alone: every receiver of the hoist down is a death at once (before its
    nodes fall silent); a receiver down of two is not; the next frame is a birth."""
    from ropemon.station.alarms import ActiveAlarm
    from ropemon.station.mqtt import DEVICE, SparkplugValues
    from ropemon.station.pipeline import AlarmState

    face = SimpleNamespace(queue=queue.SimpleQueue(), config=SimpleNamespace(report="frame"))
    v = SparkplugValues(face, "h0", [1], silent_s=5.0)
    status = SimpleNamespace(time_s=100.0, receivers={"pithead": SimpleNamespace(url="/dev/ttyUSB0"),
                                                      "bank": SimpleNamespace(url="/dev/ttyUSB1")})

    def down(*names):
        return AlarmState(100.0, tuple(ActiveAlarm(f"receiver_down:{n}", "receiver_down", None, None, True, True,
                                                   None, None, f"{n} down", 99.0) for n in names), {})

    def states():
        out = []
        while not face.queue.empty():
            _, _, values = face.queue.get()
            if DEVICE in values:
                out.append(values[DEVICE])
        return out

    v.on_status(status)
    v.on_alarms(down("pithead"))
    assert states() == [] and v.alive
    v.on_status(status)
    v.on_alarms(down("pithead", "bank"))
    assert states() == ["death"] and not v.alive
    v.on_status(status)
    v.on_alarms(down("pithead", "bank"))
    assert states() == []                                     # said once
    from ropemon.station.scadavalues import NodeValues
    v.changed("frame", NodeValues(1, 7, time.time(), 100.1, 0, 0, (), None, 0, 0, 12000, None))
    assert states() == ["birth"] and v.alive
    v.on_status(status)
    v.on_alarms(down("pithead", "bank"))                     # still down by the alarm's clearing time
    assert states() == [] and v.alive


def test_births_wait_for_the_primary_host_and_end_when_it_goes_offline(tmp_path, broker, caplog):
    caplog.set_level(logging.WARNING, logger="ropemon.station.mqtt")
    spy = RawSpy(broker.port)
    host = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="primary-host")
    host.connect("127.0.0.1", broker.port)
    host.loop_start()

    def state(online, ts, retain=True):
        host.publish("spBv1.0/STATE/scada", json.dumps({"online": online, "timestamp": ts}), qos=1,
                     retain=retain).wait_for_publish(5)

    rig = Rig(tmp_path, 1, mqtt_table(broker.port, extra='primary_host_id = "scada"\n'))
    (face,) = start_faces(rig.stations, rig.file)
    try:
        wait(lambda: face.connected, what="connected")
        for _ in range(3):
            rig.feed("h0")
        wait(lambda: face.outbox.rows == 3, what="frames kept while the primary host is away")
        time.sleep(0.5)
        assert not [t for t, *_ in spy.msgs if "/STATE/" not in t]      # no birth without the host
        assert "waiting for the primary host scada" in face.describe()
        T = int(time.time() * 1000)
        state(True, T)
        wait(lambda: len(spy.kinds("DDATA")) == 3, what="births and the stored frames")
        rig.feed("h0")
        wait(lambda: len(spy.kinds("DDATA")) == 4, what="live DDATA")
        host.publish("spBv1.0/STATE/scada", b"not json", qos=1).wait_for_publish(5)
        state(False, T - 1000, retain=False)                  # older than the newest STATE: ignored
        time.sleep(0.5)
        assert not spy.kinds("NDEATH") and face.births
        assert "STATE is not Sparkplug's" in caplog.text
        state(False, T + 1)                                   # the primary host goes offline
        wait(lambda: spy.kinds("NDEATH"), what="NDEATH when the primary host goes offline")
        wait(lambda: face.connected and not face.births, what="reconnected, waiting")
        for _ in range(2):
            rig.feed("h0")
        wait(lambda: face.outbox.rows == 2, what="frames kept while the primary host is offline")
        time.sleep(0.3)
        assert len(spy.kinds("NBIRTH")) == 1 and len(spy.kinds("DDATA")) == 4
        state(True, T + 2)
        wait(lambda: len(spy.kinds("DDATA")) == 6, what="born again, the stored frames sent")
    finally:
        face.stop()
        rig.close()
        host.disconnect()
        host.loop_stop()
    spy.close()
    decoded = tahu([m[1] for m in spy.msgs if "/STATE/" not in m[0]])
    topics = [m[0].split("/")[2] for m in spy.msgs if "/STATE/" not in m[0]]
    assert topics == ["NBIRTH", "DBIRTH", "DDATA", "DDATA", "DDATA", "DDATA", "NDEATH",
                      "NBIRTH", "DBIRTH", "DDATA", "DDATA", "NDEATH"]
    bd = [by_name(p)["bdSeq"]["value"] for p, k in zip(decoded, topics) if k in ("NBIRTH", "NDEATH")]
    assert bd[0] == bd[1] and bd[2] == bd[3] == str((int(bd[0]) + 1) % 256)
    hist = [all(m.get("isHistorical") for m in p["metrics"]) for p, k in zip(decoded, topics) if k == "DDATA"]
    assert hist == [True, True, True, False, True, True]      # queued before their session's births


def test_a_bad_primary_host_id_is_refused_with_the_field(tmp_path):
    rig = Rig(tmp_path, 1, '[mqtt]\ngroup_id = "a"\nedge_node_id = "x"\nprimary_host_id = "scada/1"\n')
    try:
        with pytest.raises(StationConfigError, match="mqtt.primary_host_id"):
            start_faces(rig.stations, rig.file)
    finally:
        rig.close()


def test_the_fleet_names_ddata_from_the_births_and_asks_a_rebirth_when_it_missed_them(tmp_path, broker):
    from ropemon.station.mqtt.fleet import Fleet, Historian
    spy = RawSpy(broker.port)
    rig = Rig(tmp_path, 2, mqtt_table(broker.port))
    (face,) = start_faces(rig.stations, rig.file)
    hist = Historian(tmp_path / "fleet.db")
    fleet = Fleet(hist, port=broker.port, group="mine", client_id="fleet-late")
    try:
        wait(lambda: len(spy.kinds("DBIRTH")) == 2, what="births")
        fleet.start()                                          # after the births: it knows no alias
        assert fleet.connected.wait(5)
        time.sleep(0.2)
        for _ in range(5):
            for h in ("h0", "h1"):
                rig.feed(h, (5000 + rig.seq[h], 5000, 4900, 5100))
        wait(lambda: hist.conn.execute("SELECT COUNT(*) FROM tension").fetchone()[0] == 2 * 5 * 4,
             what="the held DDATA written once the rebirth named them")
        assert fleet.stats["rebirths_asked"] == 1 and fleet.stats["held"] >= 1
        assert len(spy.kinds("NCMD")) == 1 and len(spy.kinds("NBIRTH")) == 2   # the station was born again
        assert face.sessions == 1                              # ... in the same session
        for _ in range(3):
            rig.feed("h0", (6000, 5000, 4900, 5100))
        wait(lambda: hist.conn.execute("SELECT COUNT(*) FROM tension").fetchone()[0] == 2 * 5 * 4 + 3 * 4,
             what="live DDATA named at once")
        assert fleet.stats["rebirths_asked"] == 1
    finally:
        face.stop()
        rig.close()
        fleet.stop()
        spy.close()
    got = hist.conn.execute("SELECT device, frame_seq, tension_kn FROM tension WHERE rope = 1 "
                            "ORDER BY device, frame_seq").fetchall()
    assert got == ([("h0", s, (5000 + s - 1) / 100) for s in range(1, 6)] + [("h0", s, 60.0) for s in (6, 7, 8)]
                   + [("h1", s, (5000 + s - 1) / 100) for s in range(1, 6)])
    # queued and sent within the session: live, the rebirth does not make them historical
    assert hist.conn.execute("SELECT COUNT(*) FROM tension WHERE historical").fetchone()[0] == 0
    # a late will of an older connection does not make the fleet forget the new session's aliases
    assert fleet.bdseq[("mine", "shaft-2")] == face.bdseq
    hist.close()


def test_tahu_reads_the_pistons_stroke_state_and_standing_status(tmp_path, broker):
    from ropemon.station.mqtt.fleet import Fleet, Historian
    spy = RawSpy(broker.port)
    hist = Historian(tmp_path / "fleet.db")
    fleet = Fleet(hist, port=broker.port, group="mine", client_id="fleet-positions")
    fleet.start()
    assert fleet.connected.wait(5)
    rig = Rig(tmp_path, 1, mqtt_table(broker.port))
    engine = rig.stations.hoists["h0"].alarms.engine
    status = SimpleNamespace(hidden_frac=0.16345, text="the seals can hide 16.3 % of a rope's tension")
    engine.hoist_status = lambda node: status if node == 1 else None   # the standing status, here the test's
    (face,) = start_faces(rig.stations, rig.file)
    try:
        wait(lambda: spy.kinds("DBIRTH"), what="birth")
        rig.feed("h0")
        rig.step()                                                         # the standing status: each tick
        rig.feed("h0", positions=(423, -455, 0, None), stroke_mask=0b0001_0010)
        rig.feed("h0", version=2)                                          # a version 2 node: no positions
        from ropemon.station.mqtt import sparkplug as sp                  # only to know when all three are out
        wait(lambda: sum(len(sp.decode(m[1]).metrics) > 10 for m in spy.kinds("DDATA")) >= 3, what="3 frames' DDATA")
        wait(lambda: hist.conn.execute("SELECT COUNT(*) FROM tension").fetchone()[0] == 3 * 4, what="the fleet's rows")
    finally:
        face.stop()
        rig.close()
        fleet.stop()
        spy.close()
    # the fleet historian keeps each rope's position beside its tension (NULL: none in that frame)
    got = hist.conn.execute("SELECT frame_seq, rope, tension_kn, position_mm FROM tension WHERE frame_seq > 1 "
                            "ORDER BY frame_seq, rope").fetchall()
    hist.close()
    assert got == [(2, 1, 50.0, 42.3), (2, 2, 51.0, -45.5), (2, 3, 49.0, 0.0), (2, 4, 50.0, None),
                   (3, 1, 50.0, None), (3, 2, 51.0, None), (3, 3, 49.0, None), (3, 4, 50.0, None)]
    msgs = [m for m in spy.msgs if m[0].split("/")[2] in ("DBIRTH", "DDATA")]
    decoded = tahu([m[1] for m in msgs])
    birth = by_name(decoded[0])
    assert birth["node1/rope1/position"]["properties"]["engUnit"]["value"] == "mm"
    assert birth["node1/rope1/position"]["type"] == "Double" and birth["node1/standing_status"]["type"] == "String"
    names = {m["alias"]: m["name"] for m in decoded[0]["metrics"]}
    frames = [{names[m["alias"]]: m for m in p["metrics"]} for p in decoded[1:]]
    frames = [d for d in frames if "node1/frame_seq" in d]
    assert [int(d["node1/frame_seq"]["value"]) for d in frames] == [1, 2, 3]
    _, v3, v2 = frames
    assert [v3[f"node1/rope{r}/position"]["value"] for r in range(1, 5)] == [42.3, -45.5, 0.0, None]
    assert [(v3[f"node1/rope{r}/near_retracted_end"]["value"], v3[f"node1/rope{r}/near_extended_end"]["value"])
            for r in range(1, 5)] == [(False, True), (True, False), (False, False), (False, False)]
    assert all(v2[f"node1/rope{r}/position"]["value"] is None for r in range(1, 5))
    assert all(v2[f"node1/rope{r}/near_extended_end"]["value"] is None for r in range(1, 5))
    assert v3["node1/hidden_imbalance"]["value"] == 16.345
    texts = [names[m["alias"]] for p in decoded[1:] for m in p["metrics"] if names[m["alias"]] == "node1/standing_status"]
    assert len(texts) == 1                                                 # sent when it changes, not each frame
    sent = next(m for p in decoded[1:] for m in p["metrics"] if names[m["alias"]] == "node1/standing_status")
    assert sent["value"] == status.text


def test_report_exception_sends_a_position_once_it_moved_by_the_mm_deadband():
    """SparkplugValues alone, report = "exception": a piston position goes out when it moved by
    the `mm` deadband (0.5 mm by default) since last reported, a stroke state when it changes."""
    from ropemon.station.mqtt import DEADBANDS, SparkplugValues
    from ropemon.station.scadavalues import STROKE_HIGH, NodeValues, RopeValue

    face = SimpleNamespace(queue=queue.SimpleQueue(), config=SimpleNamespace(report="exception",
                                                                             deadband=dict(DEADBANDS)))
    v = SparkplugValues(face, "h0", [1])
    assert DEADBANDS["mm"] == 0.5

    def frame(seq, pos, stroke=0):
        ropes = (RopeValue(5000, 0.0, pos, stroke),) + (RopeValue(5000, 0.0, 0, 0),) * 3
        v.changed("frame", NodeValues(1, seq, time.time(), 100.0, 0, 0, ropes, 20000, 0, 0, 12000, None, 3, 0))
        out = {}
        while not face.queue.empty():
            out.update(face.queue.get()[2])
        return out
    assert frame(1, 100)["node1/rope1/position"] == 10.0
    assert "node1/rope1/position" not in frame(2, 104)             # 0.4 mm: within the deadband
    assert frame(3, 105)["node1/rope1/position"] == 10.5           # 0.5 mm since last reported
    got = frame(4, 105, STROKE_HIGH)
    assert got["node1/rope1/near_extended_end"] is True and "node1/rope1/position" not in got


def test_the_standing_status_text_goes_out_when_it_changes_at_most_every_10_s():
    """SparkplugValues alone: the text follows the mean rope tension, so it is sent when it
    changes, at most every STANDING_EVERY_S (then the newest); hidden_imbalance with each frame."""
    from ropemon.station.mqtt import STANDING_EVERY_S, SparkplugValues
    from ropemon.station.pipeline import AlarmState

    face = SimpleNamespace(queue=queue.SimpleQueue(), config=SimpleNamespace(report="frame"))
    v = SparkplugValues(face, "h0", [1], silent_s=1e9)
    assert STANDING_EVERY_S == 10.0

    def tick(t, text):
        v.on_status(SimpleNamespace(time_s=t, receivers={}))
        v.on_alarms(AlarmState(t, (), {}, (), {1: SimpleNamespace(hidden_frac=0.2, text=text)}))
        out = []
        while not face.queue.empty():
            out += [x for k, x in face.queue.get()[2].items() if k == "node1/standing_status"]
        return out
    assert tick(100.0, "a") == ["a"]
    assert tick(101.0, "b") == []            # changed within 10 s: held back
    assert tick(105.0, "c") == []
    assert tick(110.0, "c") == ["c"]         # the newest, once 10 s passed
    assert tick(125.0, "c") == []            # unchanged: not sent again
