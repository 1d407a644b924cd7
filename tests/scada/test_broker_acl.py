"""The broker's ACL of docs/integration.md, as written there, in a real Mosquitto: a station
publishes under its own login and the fleet consumer stores its frames; another station's
login (and an anonymous client) cannot publish into its namespace: a forged DDATA for a frame
the station has not sent yet, a forged NBIRTH and DBIRTH reach nobody, and the station's own
frame is stored as it sent it."""
from __future__ import annotations

import re
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("paho.mqtt")

import paho.mqtt.client as paho  # noqa: E402

from ropemon.lab.localnet import Broker, available  # noqa: E402
from ropemon.station.faces import start_faces  # noqa: E402
from ropemon.station.mqtt import sparkplug as sp  # noqa: E402
from ropemon.station.mqtt.fleet import Fleet, Historian  # noqa: E402
from scada_rig import Rig, wait  # noqa: E402

DOC = Path(__file__).resolve().parents[2] / "docs" / "integration.md"
USERS = {"shaft-2": "s2-secret", "shaft-3": "s3-secret", "fleet": "fleet-secret", "scada": "scada-secret"}


def doc_acl() -> str:
    """The ACL file of docs/integration.md (the fenced block that begins `# ropemon.acl`)."""
    blocks = re.findall(r"^```[a-z]*\n(.*?)^```$", DOC.read_text(), re.S | re.M)
    (acl,) = [b for b in blocks if b.startswith("# ropemon.acl")]
    return acl


@pytest.fixture
def acl_broker(tmp_path):
    if not available():
        pytest.fail("mosquitto is missing: `make test` installs it (apt-get install mosquitto, as root)")
    b = Broker(tmp_path, users=USERS)
    acl = b.dir / "ropemon.acl"
    acl.write_text(doc_acl())
    b.conf.write_text(b.conf.read_text() + f"acl_file {acl}\nmax_packet_size 131072\n")
    b.restart()
    yield b
    b.close()


def client(port: int, user: str | None, cid: str) -> tuple[paho.Client, object]:
    c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=cid)
    if user is not None:
        c.username_pw_set(user, USERS[user])
    got: list = []
    done = threading.Event()
    c.on_connect = lambda cl, u, f, reason, p: (got.append(reason), done.set())
    c.connect("127.0.0.1", port)
    c.loop_start()
    assert done.wait(5), f"no CONNACK for {user}"
    return c, got[0]


def forge(port: int, user: str, topic: str, data: bytes) -> None:
    """Publish once (QoS 1) under `user`, on a connection of its own, until the broker has dealt with
    it: a PUBACK, or the connection closed (Mosquitto does either with a PUBLISH it denies; MQTT
    3.1.1 lets it)."""
    c, reason = client(port, user, f"forger-{time.monotonic_ns()}")
    assert not reason.is_failure                               # a real login
    done = threading.Event()
    c.on_publish = lambda *a: done.set()
    c.on_disconnect = lambda *a: done.set()
    c.publish(topic, data, qos=1)
    assert done.wait(5), f"neither a PUBACK nor a disconnection for {topic}"
    c.disconnect()
    c.loop_stop()


def test_only_the_stations_login_publishes_into_its_namespace(tmp_path, acl_broker):
    port = acl_broker.port
    anon, reason = client(port, None, "anon")
    assert reason.is_failure                                   # anonymous: refused
    anon.disconnect()
    anon.loop_stop()

    hist = Historian(tmp_path / "fleet.db")
    fleet = Fleet(hist, port=port, group="mine", client_id="fleet-acl", username="fleet", password=USERS["fleet"])
    fleet.start()
    assert fleet.connected.wait(10)
    time.sleep(0.2)
    (tmp_path / "mqtt-password").write_text(USERS["shaft-2"] + "\n")
    rig = Rig(tmp_path, 1, '[mqtt]\nport = %d\ngroup_id = "mine"\nedge_node_id = "shaft-2"\n'
              'username = "shaft-2"\npassword_file = "mqtt-password"\n' % port)
    (face,) = start_faces(rig.stations, rig.file)

    def rows() -> list[tuple]:
        return hist.conn.execute("SELECT frame_seq, tension_kn FROM tension WHERE rope = 1 "
                                 "ORDER BY frame_seq").fetchall()

    try:
        wait(lambda: face.connected and face.sessions == 1 and fleet.stats["births"] >= 1, 10,
             "the station born under its login, the fleet hearing it")
        for _ in range(3):
            rig.feed("h0", (5000 + rig.seq["h0"], 5000, 4900, 5100))
        wait(lambda: len(rows()) == 3, 10, "the station's frames in the historian")
        alias = face.alias["h0"]
        forged = sp.payload(200)                               # well formed: the station's aliases
        sp.add_metric(forged, None, sp.UINT64, 4, forged.timestamp, alias=alias["node1/frame_seq"])
        sp.add_metric(forged, None, sp.DOUBLE, 999.0, forged.timestamp, alias=alias["node1/rope1/tension"])
        nbirth = sp.payload(0)
        sp.add_metric(nbirth, "bdSeq", sp.INT64, 77, nbirth.timestamp)
        dbirth = sp.payload(1)
        sp.add_metric(dbirth, "node1/frame_seq", sp.UINT64, None, dbirth.timestamp, alias=1)
        for kind, device, p in (("NBIRTH", None, nbirth), ("DBIRTH", "h0", dbirth), ("DDATA", "h0", forged)):
            forge(port, "shaft-3", sp.topic("mine", kind, "shaft-2", device), p.SerializeToString())   # another station's login
        births = fleet.stats["births"]
        rig.feed("h0", (5000 + rig.seq["h0"], 5000, 4900, 5100))   # the station's own frame 4
        wait(lambda: len(rows()) == 4, 10, "the station's frame 4")
        with fleet.lock:                                       # the consumer's NCMD reaches the station
            fleet._ask_rebirth("mine", "shaft-2")
        wait(lambda: fleet.stats["births"] > births, 10, "the station born again at the consumer's NCMD")
    finally:
        face.stop()
        rig.close()
        fleet.stop()
    assert rows() == [(1, 50.0), (2, 50.01), (3, 50.02), (4, 50.03)]   # frame 4 as the station sent it
    assert births == 1                                          # the forged NBIRTH reached nobody
    assert fleet.stats["refused_messages"] == 0 and fleet.stats["held"] == 0
    hist.close()
