"""`ropemon demo --station examples/station.toml --serve`: the shipped example station file serves
every face it configures (web, OPC UA, Modbus TCP, MQTT Sparkplug B) while the demo's wind plays
through its first hoist, each answering a real client, and the headless demo stops at the wind's
end (exit 0, the faces' ports closed). Without a broker the demo names the broker it cannot
reach and the other faces serve all the same.

The example runs from a copy beside a link to firmware/ (its node config is ../firmware/node.json),
only its four ports moved to free ones: the repository's examples/ stays as shipped (the station
makes web-secret and opcua-pki/ beside its file) and the fixed ports may be taken on a shared machine.
"""
from __future__ import annotations

import asyncio
import json
import socket
import threading
import time
import urllib.request
from pathlib import Path

import pytest

for _lib in ("starlette", "uvicorn", "asyncua", "pymodbus", "paho.mqtt"):
    pytest.importorskip(_lib)

import paho.mqtt.client as paho  # noqa: E402
from asyncua import Client  # noqa: E402
from pymodbus.client import ModbusTcpClient  # noqa: E402

from ropemon.lab.localnet import Broker, available  # noqa: E402
from ropemon.station import modbus as M  # noqa: E402
from ropemon.station.mqtt import sparkplug as sp  # noqa: E402
from test_demo_serve import ROOT, _demo, _free  # noqa: E402

EXAMPLE = ROOT / "examples" / "station.toml"
SPEED = "0.5"            # short-test's 7 s wind served for 14 s: time for every client to get its answer


def example_copy(tmp: Path, ports: dict[str, int]) -> Path:
    """examples/station.toml in tmp/examples/ beside tmp/firmware (a link), its ports replaced."""
    (tmp / "firmware").symlink_to(ROOT / "firmware", target_is_directory=True)
    (tmp / "examples").mkdir()
    text = EXAMPLE.read_text()
    for old, new in [("port = 8080 ", f"port = {ports['web']} "),
                     ('"opc.tcp://127.0.0.1:4840/ropemon"', f'"opc.tcp://127.0.0.1:{ports["opcua"]}/ropemon"'),
                     ("port = 5020 ", f"port = {ports['modbus']} "),
                     ("port = 1883 ", f"port = {ports['mqtt']} ")]:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp / "examples" / "station.toml"
    path.write_text(text)
    return path


class Sparkplug:
    """The Sparkplug B messages of group `mine` on the broker: (type, device) seen."""

    def __init__(self, port: int) -> None:
        self.seen: set[tuple[str, str]] = set()
        ready = threading.Event()
        c = self.c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="example-spy")
        c.on_connect = lambda cl, *a: (cl.subscribe("spBv1.0/mine/#", qos=1), ready.set())
        c.on_message = self._on_message
        c.connect("127.0.0.1", port)
        c.loop_start()
        assert ready.wait(5)

    def _on_message(self, client, userdata, m) -> None:
        sp.decode(m.payload)                           # a Sparkplug B payload
        parts = m.topic.split("/")                     # spBv1.0/mine/TYPE/shaft-2[/device]
        self.seen.add((parts[2], parts[4] if len(parts) > 4 else parts[3]))

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()


def probe_faces(ports: dict[str, int], stop: threading.Event, spy: Sparkplug | None) -> dict[str, object]:
    """Ask every face until each has answered with the wind's data, or `stop`: what each said."""
    got: dict[str, object] = {}
    url = f"http://127.0.0.1:{ports['web']}"

    def web():
        with urllib.request.urlopen(url + "/", timeout=3) as r:
            page = r.read().decode()
        with urllib.request.urlopen(url + "/hoist/north/snapshot.json", timeout=3) as r:
            snap = json.load(r)
        if "North shaft (rock)" in page and "South shaft (service)" in page and snap["nodes"]:
            return {"nodes": sorted(snap["nodes"])}

    def modbus():
        c = ModbusTcpClient("127.0.0.1", port=ports["modbus"], timeout=3)
        try:
            if not c.connect():
                return None
            head = c.read_holding_registers(0, count=2)
            north = c.read_holding_registers(M.HOIST_BASE + M.FRAMES, count=1)
            if not head.isError() and not north.isError() and north.registers[0] > 0:
                return {"version": head.registers[0], "hoists": head.registers[1]}
        finally:
            c.close()

    def opcua():
        async def go():
            c = Client(f"opc.tcp://127.0.0.1:{ports['opcua']}/ropemon", timeout=5)
            return await c.connect_and_get_server_endpoints()
        eps = asyncio.run(go())
        return sorted({e.SecurityPolicyUri.rsplit("#", 1)[-1] for e in eps})

    def mqtt():
        if spy is not None and {("NBIRTH", "shaft-2"), ("DBIRTH", "north"), ("DBIRTH", "south"),
                                ("DDATA", "north")} <= spy.seen:
            return sorted(spy.seen)

    todo = {"web": web, "modbus": modbus, "opcua": opcua, **({"mqtt": mqtt} if spy is not None else {})}
    errors: dict[str, str] = {}
    while todo and not stop.is_set():
        for name, ask in list(todo.items()):
            try:
                answer = ask()
            except (OSError, ConnectionError, asyncio.TimeoutError, TimeoutError) as e:
                errors[name] = repr(e)
                continue
            if answer is not None:
                got[name] = answer
                del todo[name]
        time.sleep(0.2)
    got["unanswered"] = {name: errors.get(name, "no data") for name in todo}
    return got


def run_example(tmp_path: Path, ports: dict[str, int], spy: Sparkplug | None):
    station = example_copy(tmp_path, ports)
    stop = threading.Event()
    answers: dict[str, object] = {}
    prober = threading.Thread(target=lambda: answers.update(probe_faces(ports, stop, spy)), daemon=True)
    prober.start()
    try:
        r = _demo(tmp_path / "out", "--station", str(station), "--serve", "--speed", SPEED)
    finally:
        stop.set()
        prober.join(30)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert r.stdout.startswith("ropemon demo summary")
    for port in (ports["web"], ports["opcua"], ports["modbus"]):    # stopped: nobody listens any more
        with pytest.raises(OSError):
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
    # the example's node config lacks the simulated node's key: the demo's logs, not the file's
    assert "(the simulated node's frames stay out of the file's own)" in r.stderr
    assert not (station.parent / "data" / "north.db").exists()
    assert "log in as demo / " in r.stderr, r.stderr
    return r, answers


def test_the_example_station_serves_every_face_through_the_demo(tmp_path):
    if not available():
        pytest.fail("mosquitto is missing: `make test` installs it (apt-get install mosquitto, as root)")
    broker = Broker(tmp_path)
    spy = Sparkplug(broker.port)
    try:
        ports = {"web": _free(), "opcua": _free(), "modbus": _free(), "mqtt": broker.port}
        r, answers = run_example(tmp_path, ports, spy)
    finally:
        spy.close()
        broker.close()
    assert answers.pop("unanswered") == {}, r.stderr[-3000:]
    assert answers["web"] == {"nodes": ["1"]}
    assert answers["modbus"] == {"version": M.MAP_VERSION, "hoists": 2}
    assert answers["opcua"] == ["Basic256Sha256"]
    assert ("NDEATH", "shaft-2") in spy.seen, sorted(spy.seen)      # its clean disconnect at the end
    for line in ("web: http://127.0.0.1:", "OPC UA on opc.tcp://127.0.0.1:", "Modbus TCP on 127.0.0.1:",
                 f"MQTT Sparkplug B to 127.0.0.1:{broker.port}"):
        assert line in r.stderr, line
    assert "cannot connect" not in r.stderr


def test_without_a_broker_the_demo_names_it_and_the_other_faces_serve(tmp_path):
    ports = {"web": _free(), "opcua": _free(), "modbus": _free(), "mqtt": _free()}   # nobody there
    r, answers = run_example(tmp_path, ports, None)
    assert answers.pop("unanswered") == {}, r.stderr[-3000:]
    assert set(answers) == {"web", "modbus", "opcua"}
    assert f"MQTT: cannot connect to 127.0.0.1:{ports['mqtt']}" in r.stderr, r.stderr[-3000:]
