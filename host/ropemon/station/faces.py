"""The station's faces beyond the terminal: the web page, OPC UA, Modbus TCP, MQTT.

Each face is a module with

    def parse_table(table, base: Path) -> Config     # not the web's: see below
    def start(view: StationView, config: Config) -> Face

`parse_table` checks the face's table of the station file (`StationConfig.sections[name]`;
relative paths taken from `base`, the file's folder) into a frozen dataclass, refusing it
with StationConfigError naming the field. The web's table is checked with the rest of the
file (`StationConfig.web`, a `WebConfig`). `start_faces` imports every face's module and
checks every table before it starts any face; then each `start` adds the face's listener to
every hoist (`StationView.add_listeners`, before the receivers open) and runs its server in
its own thread(s); the returned object has `stop()` and `describe()` (one line: where it
listens). A face uses the station only through `StationView`. A face's heavy libraries are
an extra (`pip install 'ropemon[web]'`), imported only when its table is present.
"""
from __future__ import annotations

import importlib
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, Callable, Mapping, Protocol, runtime_checkable

from ropemon.station.stationfile import HoistConfig, StationConfig

if TYPE_CHECKING:
    from ropemon.station.commands import Command, Ticket
    from ropemon.station.pipeline import Listener
    from ropemon.station.nodefigures import NodeFigures

#: face -> (module, extra that installs its libraries)
FACES = {
    "web": ("ropemon.station.web.server", "web"),
    "opcua": ("ropemon.station.opcua", "opcua"),
    "modbus": ("ropemon.station.modbus", "modbus"),
    "mqtt": ("ropemon.station.mqtt", "mqtt"),
}


@runtime_checkable
class HoistView(Protocol):
    """What the faces read of one hoist (`assembly.Hoist`)."""

    @property
    def id(self) -> str: ...

    @property
    def name(self) -> str: ...

    @property
    def keys(self) -> dict[int, bytes]: ...          # its nodes (their keys are not the faces')

    @property
    def figures(self) -> NodeFigures: ...            # from its node configs: areas, strokes, rated loads

    @property
    def config(self) -> HoistConfig | None: ...      # receivers, node configs, shaft depth

    @property
    def db_path(self) -> Path | None: ...            # its log, read through the faces' own readers


@runtime_checkable
class StationView(Protocol):
    """What the faces use of the station (`hoists.Station`)."""

    @property
    def config(self) -> StationConfig: ...           # name, data_dir, silent_s

    @property
    def hoists(self) -> Mapping[str, HoistView]: ...  # in the station file's order

    def add_listeners(self, factory: Callable[[HoistView], Listener | None]) -> None: ...

    def submit(self, hoist_id: str, command: Command) -> Ticket: ...


class Face(Protocol):
    def stop(self) -> None: ...

    def describe(self) -> str: ...


class FaceError(RuntimeError):
    """A face that cannot start: its extra is not installed, or its table is refused."""


def configured(sf: StationConfig) -> dict[str, Any]:
    """The faces the station file asks for, with their tables (the web's already a WebConfig)."""
    out: dict[str, Any] = {}
    if sf.web is not None:
        out["web"] = sf.web
    for name, table in sf.sections.items():
        out[name] = table
    return out


def _module(name: str) -> ModuleType:
    module, extra = FACES[name]
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise FaceError(f"[{name}]: the {name} face needs its libraries: pip install 'ropemon[{extra}]' "
                        f"({e})") from None


def parse_faces(sf: StationConfig) -> list[tuple[str, ModuleType, Any]]:
    """(name, module, config) of every face the station file asks for, every table checked and
    nothing started: FaceError for a face whose extra is missing, StationConfigError naming
    the field of a table refused."""
    out = []
    for name, table in configured(sf).items():
        mod = _module(name)
        out.append((name, mod, table if name == "web" else mod.parse_table(table, sf.path.parent)))
    return out


def start_faces(view: StationView, sf: StationConfig) -> list[Face]:
    """Check every face's table (`parse_faces`), then start each; on a failure stop those
    started, raise FaceError (or the table's StationConfigError, before any face starts)."""
    parsed = parse_faces(sf)
    started: list[Face] = []
    try:
        for name, mod, config in parsed:
            try:
                started.append(mod.start(view, config))
            except OSError as e:               # its port taken, a certificate unreadable: the face's own words
                raise FaceError(f"[{name}]: cannot start: {e}") from None
    except Exception:
        for f in started:
            f.stop()
        raise
    return started
