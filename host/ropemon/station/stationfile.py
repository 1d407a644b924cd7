"""The station file (station.toml): the hoists one station watches and the faces it serves.

    [station]                       # optional
    name = "No. 2 shaft"
    data_dir = "/var/lib/ropemon"   # each hoist's log: <data_dir>/<hoist id>.db; absent: no logs
    silent_s = 5.0                  # NODE SILENT after this many seconds without a frame
    tick_hz = 4.0                   # the station's ticks (alarm timing, status) per second

    [[hoist]]                       # one or more
    id = "north"                    # a-z, 0-9 and '-': in URLs, file names, SCADA paths
    name = "North shaft"            # shown to people (default: the id)
    configs = ["north-node.json"]   # the node.json of each cage node (ids and keys come from them)
    receivers = { pithead = "/dev/serial/by-id/usb-FTDI-pithead", mid-shaft = "socket://gw:4001" }
    baud = 115200
    rs485 = false
    shaft_m = 806.0                 # optional: the shaft's depth (web page's shaft diagram)

    [web]                           # optional: `ropemon serve` (docs/web.md)
    bind = "127.0.0.1"
    port = 8080
    view_without_login = true
    users = "users.toml"            # operators and their roles (`ropemon user`)
    session_idle_min = 30.0         # a login unused this many minutes ends (1-720)
    tls_cert = "..."                # optional, with tls_key

Relative paths are taken from the station file's folder. Every refusal names the field
and the reason; unknown tables and fields are refused (`station.tomlfields`).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from ropemon.station import tomlfields
from ropemon.station.tomlfields import Table
from ropemon.station import files

MAX_STATION_TOML = 1 * files.MB
HOIST_ID = re.compile(r"^[a-z0-9][a-z0-9-]{0,31}$")
RECEIVER_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,31}$")


class StationConfigError(ValueError):
    """A station file that cannot be used: the message names the field and the reason."""


@dataclass(frozen=True)
class HoistConfig:
    id: str
    name: str
    configs: tuple[Path, ...]
    receivers: tuple[tuple[str, str], ...]   # (name, pyserial URL), in the order given
    baud: int = 115200
    rs485: bool = False
    shaft_m: float | None = None             # depth of the shaft (the web page's shaft diagram, trip rests)


@dataclass(frozen=True)
class WebConfig:
    bind: str = "127.0.0.1"
    port: int = 8080
    view_without_login: bool = True
    users: Path | None = None
    secret: Path | None = None      # the session cookies' signing key (made 0600 on first start)
    tls_cert: Path | None = None
    tls_key: Path | None = None
    session_idle_min: float = 30.0  # a web session unused this long ends (docs/web.md)


@dataclass(frozen=True)
class StationConfig:
    path: Path
    name: str
    data_dir: Path | None
    silent_s: float
    tick_hz: float
    hoists: tuple[HoistConfig, ...]
    web: WebConfig | None = None
    sections: dict[str, dict] = field(default_factory=dict)  # further faces' tables, checked by their modules

    def hoist(self, hoist_id: str) -> HoistConfig:
        for h in self.hoists:
            if h.id == hoist_id:
                return h
        raise KeyError(hoist_id)


#: Tables a later face checks itself (its module parses `sections[name]`).
FACE_TABLES = ("opcua", "modbus", "mqtt")


def load_station_file(path: str | Path) -> StationConfig:
    """Read and check a station file; StationConfigError names the field and the reason."""
    path = Path(path)
    doc = tomlfields.load(path, StationConfigError, "station file", MAX_STATION_TOML)
    return parse_station(doc, path)


def parse_station(doc: dict, path: Path) -> StationConfig:
    base = path.parent
    top = Table(doc, "", StationConfigError)
    st = top.table("station", {})
    name = st.string("name", path.stem)
    data_dir = _path(base, st.string("data_dir", "")) if st.has("data_dir") else None
    silent_s = st.number("silent_s", 5.0, gt=0.0, le=3600.0)
    tick_hz = st.number("tick_hz", 4.0, ge=0.5, le=50.0)
    st.finish()
    hoists_raw = top.array("hoist")
    if not hoists_raw:
        raise StationConfigError("hoist: at least one [[hoist]] is needed")
    hoists = tuple(_hoist(Table(h, f"hoist[{i}]", StationConfigError), base) for i, h in enumerate(hoists_raw))
    seen: set[str] = set()
    for i, h in enumerate(hoists):
        if h.id in seen:
            raise StationConfigError(f"hoist[{i}].id: {h.id!r} is used twice")
        seen.add(h.id)
    web = _web(top.table("web"), base) if top.has("web") else None
    sections = {}
    for face in FACE_TABLES:
        if top.has(face):
            sections[face] = top.table(face).data
    top.finish()
    return StationConfig(path, name, data_dir, silent_s, tick_hz, hoists, web, sections)


def _path(base: Path, text: str) -> Path:
    p = Path(text)
    return p if p.is_absolute() else base / p


def _hoist(t: Table, base: Path) -> HoistConfig:
    hid = t.string("id")
    if not HOIST_ID.match(hid):
        raise StationConfigError(f"{t.field('id')}: {hid!r} must be 1-32 of a-z, 0-9 and '-', starting with a letter "
                                 "or digit")
    configs = t.array("configs")
    if not configs or not all(isinstance(c, str) and c for c in configs):
        raise StationConfigError(f"{t.field('configs')}: must be a list of one or more node.json paths")
    rx = t.table("receivers")
    receivers = []
    for name, url in rx.data.items():
        if not RECEIVER_NAME.match(name):
            raise StationConfigError(f"{rx.field(name)}: a receiver name is 1-32 letters, digits, '_', '.' or '-'")
        if not isinstance(url, str) or not url:
            raise StationConfigError(f"{rx.field(name)}: must be a device path or a pyserial URL, got {url!r}")
        receivers.append((name, url))
        rx.used.add(name)
    if not receivers:
        raise StationConfigError(f"{t.field('receivers')}: at least one receiver is needed")
    h = HoistConfig(hid, t.string("name", hid), tuple(_path(base, c) for c in configs), tuple(receivers),
                    t.integer("baud", 115200, lo=1200, hi=4_000_000), t.boolean("rs485", False),
                    t.number("shaft_m", gt=0.0, le=5000.0) if t.has("shaft_m") else None)
    t.finish()
    return h


def _web(t: Table, base: Path) -> WebConfig:
    def opt_path(key: str) -> Path | None:
        return _path(base, t.string(key)) if t.has(key) else None

    w = WebConfig(t.string("bind", "127.0.0.1"), t.integer("port", 8080, lo=1, hi=65535),
                  t.boolean("view_without_login", True), opt_path("users"), opt_path("secret"),
                  opt_path("tls_cert"), opt_path("tls_key"),
                  t.number("session_idle_min", 30.0, ge=1.0, le=720.0))
    t.finish()
    if (w.tls_cert is None) != (w.tls_key is None):
        raise StationConfigError("web.tls_cert, web.tls_key: give both or neither")
    return w
