"""The station file's [mqtt] table, checked (docs/integration.md lists its fields)."""
from __future__ import annotations

import re
from pathlib import Path

from ropemon.station.stationfile import StationFileError
from ropemon.station.tomlfields import Table

SPARKPLUG_ID = re.compile(r"^[^/+#]{1,64}$")
DEADBANDS = {"kN": 0.5, "%": 0.1, "m": 0.1, "mm": 0.5, "m/s": 0.05, "V": 0.05, "degC": 0.5}


class Settings:
    """The [mqtt] table's fields, each checked; paths relative to the station file's folder (`base`)."""

    host: str
    port: int
    group_id: str
    edge_node_id: str
    client_id: str
    report: str                      # "frame" | "exception"
    deadband: dict[str, float]       # unit -> change needed (report = "exception")
    qos: int                         # DDATA's QoS, 0 or 1
    keepalive_s: int
    username: str | None
    password_file: Path | None
    tls: bool
    tls_ca: Path | None
    tls_cert: Path | None
    tls_key: Path | None
    buffer_max_frames: int
    primary_host_id: str | None

    def __init__(self, table: dict, base: Path, station_name: str) -> None:
        t = Table(table, "mqtt", StationFileError)
        self.host = t.string("host", "127.0.0.1")
        self.port = t.integer("port", 1883, lo=1, hi=65535)
        self.group_id = t.string("group_id")
        self.edge_node_id = t.string("edge_node_id")
        for key in ("group_id", "edge_node_id"):
            if not SPARKPLUG_ID.match(getattr(self, key)):
                raise StationFileError(f"mqtt.{key}: 1-64 characters, none of '/', '+', '#'")
        self.client_id = t.string("client_id", f"ropemon-{self.edge_node_id}")
        self.report = t.string("report", "frame", choices=("frame", "exception"))
        db = t.table("deadband", {})
        self.deadband = dict(DEADBANDS)
        for unit in list(db.data):
            if unit not in DEADBANDS:
                raise StationFileError(f"{db.field(unit)}: a unit of the metrics: {', '.join(DEADBANDS)}")
            self.deadband[unit] = db.number(unit, ge=0.0)
        db.finish()
        self.qos = t.integer("qos", 1, lo=0, hi=1)
        self.keepalive_s = t.integer("keepalive_s", 10, lo=2, hi=600)
        self.username = t.string("username", "") or None
        pw = t.string("password_file", "")
        self.password_file = _path(base, pw) if pw else None
        if self.password_file is not None and self.username is None:
            raise StationFileError("mqtt.password_file: needs mqtt.username")
        self.tls = t.boolean("tls", False)
        self.tls_ca = _path(base, t.string("tls_ca")) if t.has("tls_ca") else None
        self.tls_cert = _path(base, t.string("tls_cert")) if t.has("tls_cert") else None
        self.tls_key = _path(base, t.string("tls_key")) if t.has("tls_key") else None
        if (self.tls_cert is None) != (self.tls_key is None):
            raise StationFileError("mqtt.tls_cert, mqtt.tls_key: give both or neither")
        self.buffer_max_frames = t.integer("buffer_max_frames", 2_000_000, lo=1000, hi=100_000_000)
        self.primary_host_id = t.string("primary_host_id", "") or None
        if self.primary_host_id is not None and not SPARKPLUG_ID.match(self.primary_host_id):
            raise StationFileError("mqtt.primary_host_id: 1-64 characters, none of '/', '+', '#'")
        t.finish()

    def password(self) -> str | None:
        """The password file's text, stripped (None without a password_file)."""
        if self.password_file is None:
            return None
        from ropemon.station import files
        return files.read_text(self.password_file, "MQTT password file", files.MAX_KEY_FILE,
                               StationFileError).strip()


def _path(base: Path, text: str) -> Path:
    p = Path(text)
    return p if p.is_absolute() else base / p
