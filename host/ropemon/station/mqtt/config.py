"""The station file's [mqtt] table, checked into an `MqttConfig` (docs/integration.md lists its fields)."""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ropemon.station.stationfile import StationConfigError
from ropemon.station.tomlfields import Table

SPARKPLUG_ID = re.compile(r"^[^/+#]{1,64}$")
DEADBANDS = {"kN": 0.5, "%": 0.1, "m": 0.1, "mm": 0.5, "m/s": 0.05, "V": 0.05, "degC": 0.5}


@dataclass(frozen=True)
class MqttConfig:
    """The [mqtt] table's fields, each checked (`parse_table`); paths relative to the station file's folder."""

    group_id: str
    edge_node_id: str
    host: str = "127.0.0.1"
    port: int = 1883
    client_id: str = ""
    report: str = "frame"            # "frame" | "exception"
    deadband: dict[str, float] = field(default_factory=lambda: dict(DEADBANDS))  # unit -> change needed
    qos: int = 1                     # DDATA's QoS, 0 or 1
    keepalive_s: int = 10
    username: str | None = None
    password_file: Path | None = None
    tls: bool = False
    tls_ca: Path | None = None
    tls_cert: Path | None = None
    tls_key: Path | None = None
    buffer_max_frames: int = 2_000_000
    primary_host_id: str | None = None

    def password(self) -> str | None:
        """The password file's text, stripped (None without a password_file)."""
        if self.password_file is None:
            return None
        from ropemon.station import files
        return files.read_text(self.password_file, "MQTT password file", files.MAX_KEY_FILE,
                               StationConfigError).strip()


def parse_table(table: Any, base: Path) -> MqttConfig:
    """The [mqtt] table, checked; StationConfigError names the field. `base`: the station file's folder."""
    t = Table(table, "mqtt", StationConfigError)
    host = t.string("host", "127.0.0.1")
    port = t.integer("port", 1883, lo=1, hi=65535)
    ids = {key: t.string(key) for key in ("group_id", "edge_node_id")}
    for key, value in ids.items():
        if not SPARKPLUG_ID.match(value):
            raise StationConfigError(f"mqtt.{key}: 1-64 characters, none of '/', '+', '#'")
    client_id = t.string("client_id", f"ropemon-{ids['edge_node_id']}")
    report = t.string("report", "frame", choices=("frame", "exception"))
    db = t.table("deadband", {})
    deadband = dict(DEADBANDS)
    for unit in list(db.data):
        if unit not in DEADBANDS:
            raise StationConfigError(f"{db.field(unit)}: a unit of the metrics: {', '.join(DEADBANDS)}")
        deadband[unit] = db.number(unit, ge=0.0)
    db.finish()
    qos = t.integer("qos", 1, lo=0, hi=1)
    keepalive_s = t.integer("keepalive_s", 10, lo=2, hi=600)
    username = t.string("username", "") or None
    pw = t.string("password_file", "")
    password_file = _path(base, pw) if pw else None
    if password_file is not None and username is None:
        raise StationConfigError("mqtt.password_file: needs mqtt.username")
    tls = t.boolean("tls", False)
    tls_ca = _path(base, t.string("tls_ca")) if t.has("tls_ca") else None
    tls_cert = _path(base, t.string("tls_cert")) if t.has("tls_cert") else None
    tls_key = _path(base, t.string("tls_key")) if t.has("tls_key") else None
    if (tls_cert is None) != (tls_key is None):
        raise StationConfigError("mqtt.tls_cert, mqtt.tls_key: give both or neither")
    buffer_max_frames = t.integer("buffer_max_frames", 2_000_000, lo=1000, hi=100_000_000)
    primary_host_id = t.string("primary_host_id", "") or None
    if primary_host_id is not None and not SPARKPLUG_ID.match(primary_host_id):
        raise StationConfigError("mqtt.primary_host_id: 1-64 characters, none of '/', '+', '#'")
    t.finish()
    return MqttConfig(ids["group_id"], ids["edge_node_id"], host, port, client_id, report, deadband, qos,
                      keepalive_s, username, password_file, tls, tls_ca, tls_cert, tls_key, buffer_max_frames,
                      primary_host_id)


def _path(base: Path, text: str) -> Path:
    p = Path(text)
    return p if p.is_absolute() else base / p
