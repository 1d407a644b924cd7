"""The station's faces beyond the terminal: the web page, OPC UA, Modbus TCP, MQTT.

Each face is a module with

    def start(station: Station, config) -> Face

where `config` is the station file's table for it (`StationFile.web`, or the raw table in
`StationFile.sections[name]`, which the face checks itself and refuses with the field
named). `start` adds the face's listener to every hoist (`Station.add_listeners`,
before the receivers open) and runs its server in its own thread(s); the returned object
has `stop()` and `describe()` (one line: where it listens). A face's heavy libraries are
an extra (`pip install 'ropemon[web]'`), imported only when its table is present.
"""
from __future__ import annotations

import importlib
from typing import Any, Protocol

from ropemon.station.stationfile import StationFile

#: face -> (module, extra that installs its libraries)
FACES = {
    "web": ("ropemon.station.web.server", "web"),
    "opcua": ("ropemon.station.opcua", "opcua"),
    "modbus": ("ropemon.station.modbus", "modbus"),
    "mqtt": ("ropemon.station.mqtt", "mqtt"),
}


class Face(Protocol):
    def stop(self) -> None: ...

    def describe(self) -> str: ...


class FaceError(RuntimeError):
    """A face that cannot start: its extra is not installed, or its table is refused."""


def configured(sf: StationFile) -> dict[str, Any]:
    """The faces the station file asks for, with their tables."""
    out: dict[str, Any] = {}
    if sf.web is not None:
        out["web"] = sf.web
    for name, table in sf.sections.items():
        out[name] = table
    return out


def start_faces(station: Any, sf: StationFile) -> list[Face]:
    """Start every face the station file asks for; on a failure stop those started, raise FaceError."""
    started: list[Face] = []
    try:
        for name, config in configured(sf).items():
            module, extra = FACES[name]
            try:
                mod = importlib.import_module(module)
            except ImportError as e:
                raise FaceError(f"[{name}]: the {name} face needs its libraries: pip install 'ropemon[{extra}]' "
                                f"({e})") from None
            try:
                started.append(mod.start(station, config))
            except OSError as e:               # its port taken, a certificate unreadable: the face's own words
                raise FaceError(f"[{name}]: cannot start: {e}") from None
    except Exception:
        for f in started:
            f.stop()
        raise
    return started
