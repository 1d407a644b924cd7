"""The [opcua] table of the station file, checked into an `OpcuaConfig` (docs/integration.md)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

from ropemon.station.stationfile import StationConfigError
from ropemon.station.tomlfields import Table

DEFAULT_ENDPOINT = "opc.tcp://127.0.0.1:4840/ropemon"
#: Security policies the table may name (asyncua's SecurityPolicyType members); no "None".
POLICIES = ("Basic256Sha256_SignAndEncrypt", "Basic256Sha256_Sign", "Aes256Sha256RsaPss_SignAndEncrypt",
            "Aes256Sha256RsaPss_Sign", "Aes128Sha256RsaOaep_SignAndEncrypt", "Aes128Sha256RsaOaep_Sign")


@dataclass(frozen=True)
class OpcuaConfig:
    endpoint: str = DEFAULT_ENDPOINT
    certificates: Path = Path("opcua-pki")
    users: Path | None = None
    allow_anonymous: bool = False
    security: tuple[str, ...] = ("Basic256Sha256_SignAndEncrypt",)
    trusted_clients: Path | None = None   # None: any client certificate; else only those in this folder

    @property
    def rejected_clients(self) -> Path | None:
        """Where refused client certificates are written: `rejected` beside the trusted folder."""
        return None if self.trusted_clients is None else self.trusted_clients.parent / "rejected"

    @property
    def host_port(self) -> tuple[str, int]:
        u = urlparse(self.endpoint)
        return u.hostname or "", u.port or 4840


def parse_table(data: Any, base: Path) -> OpcuaConfig:
    """The [opcua] table, checked; StationConfigError names the field."""
    t = Table(data, "opcua", StationConfigError)

    def path(key: str, default: str | None) -> Path | None:
        text = t.string(key, default) if (t.has(key) or default is not None) else None
        if text is None:
            return None
        if not text:
            raise StationConfigError(f"{t.field(key)}: must not be empty")
        p = Path(text)
        return p if p.is_absolute() else base / p

    endpoint = t.string("endpoint", DEFAULT_ENDPOINT)
    u = urlparse(endpoint)
    try:
        port = u.port
    except ValueError:
        port = -1
    if u.scheme != "opc.tcp" or not u.hostname or (port is not None and not 1 <= port <= 65535):
        raise StationConfigError(f"{t.field('endpoint')}: must be opc.tcp://HOST:PORT/PATH, got {endpoint!r}")
    certs = path("certificates", "opcua-pki")
    users = path("users", None)
    anon = t.boolean("allow_anonymous", False)
    sec = t.array("security", ["Basic256Sha256_SignAndEncrypt"], min_len=1, what="security policy names")
    trusted = path("trusted_clients", None)
    for i, s in enumerate(sec):
        if s not in POLICIES:
            raise StationConfigError(f"{t.field('security')}[{i}]: must be one of {', '.join(POLICIES)}, got {s!r} "
                                     "(no unencrypted endpoint)")
    t.finish()
    if users is None and not anon:
        raise StationConfigError("opcua.users: needed unless allow_anonymous = true (nobody could log in)")
    assert certs is not None
    return OpcuaConfig(endpoint, certs, users, anon, tuple(dict.fromkeys(sec)), trusted)
