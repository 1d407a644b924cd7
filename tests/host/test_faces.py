"""The faces' one contract (station/faces.py): every table checked into a frozen config before
any face starts, each face started with `start(view, config)`, the station a `StationView`."""
from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path

import pytest

from ropemon.station import faces
from ropemon.station.hoists import Station
from ropemon.station.stationfile import StationConfigError, load_station_file

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "station.toml"     # every face's table

#: face -> (a line of its table, that line made bad, the field the refusal names)
BAD = {
    "web": ("port = 8080 ", "port = 70000 ", "web.port"),
    "opcua": ('endpoint = "opc.tcp://127.0.0.1:4840/ropemon"', 'endpoint = "http://127.0.0.1/"', "opcua.endpoint"),
    "modbus": ("port = 5020 ", "port = 70000 ", "modbus.port"),
    "mqtt": ('edge_node_id = "shaft-2"', 'edge_node_id = "shaft/2"', "mqtt.edge_node_id"),
}


@pytest.fixture
def started(monkeypatch) -> list:
    """Each face's `start` replaced by one that records (face, config) and starts nothing."""
    calls: list = []
    for name, (module, _extra) in faces.FACES.items():
        mod = importlib.import_module(module)

        class Started:
            def __init__(self, face: str) -> None:
                self.face = face

            def stop(self) -> None:
                calls.append((self.face, "stopped"))

            def describe(self) -> str:
                return self.face

        monkeypatch.setattr(mod, "start", lambda view, config, name=name: calls.append((name, config))
                            or Started(name))
    return calls


def test_every_face_is_started_with_its_table_checked_into_a_frozen_config(started):
    sf = load_station_file(EXAMPLE)
    got = faces.start_faces(object(), sf)
    assert [f.describe() for f in got] == list(faces.FACES)
    assert [name for name, _ in started] == list(faces.FACES)
    for name, config in started:
        assert dataclasses.is_dataclass(config) and type(config).__dataclass_params__.frozen, name
    assert {name: type(config).__name__ for name, config in started} == {
        "web": "WebConfig", "opcua": "OpcuaConfig", "modbus": "ModbusConfig", "mqtt": "MqttConfig"}


@pytest.mark.parametrize("face", list(BAD))
def test_a_bad_table_of_each_face_is_refused_with_its_field_before_any_face_starts(tmp_path, started, face):
    good, bad, field = BAD[face]
    text = EXAMPLE.read_text()
    assert text.count(good) == 1
    (tmp_path / "station.toml").write_text(text.replace(good, bad))
    with pytest.raises(StationConfigError, match=field.replace(".", r"\.")):
        sf = load_station_file(tmp_path / "station.toml")   # [web]: refused with the station file
        faces.start_faces(object(), sf)                   # the others: before any face starts
    assert started == []


def test_the_station_is_the_view_the_faces_use():
    station = Station(load_station_file(EXAMPLE), open_stores=False)
    try:
        assert isinstance(station, faces.StationView)
        assert all(isinstance(h, faces.HoistView) for h in station.hoists.values())
    finally:
        station.close()
