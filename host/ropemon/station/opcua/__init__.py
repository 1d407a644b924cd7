"""The OPC UA face: every hoist's ropes, alarms and history for SCADA (docs/integration.md).

    [opcua]
    endpoint = "opc.tcp://127.0.0.1:4840/ropemon"
    certificates = "opcua-pki"          # server.der and server-key.pem (0600), made on first start
    users = "users.toml"                # who may log in: the web face's users file (`ropemon user add`)
    allow_anonymous = false
    security = ["Basic256Sha256_SignAndEncrypt"]
    trusted_clients = "opcua-pki/trusted"   # optional: only these client certificates (refused ones go to
                                            # opcua-pki/rejected for an engineer to move in)

`parse_table(table, base)` checks the table (refusing it with the field named) into an
`OpcuaConfig`; `start(view, config)` adds an `OpcuaListener` to every hoist and runs an
asyncua server in its own thread with its own asyncio loop. The listener runs on the station's thread and only hands each message to
that loop (`loop.call_soon_threadsafe`, onto a bounded queue): it never waits for the
server. On the loop, frames become variable values (SourceTimestamp: the frame's receipt
time, the node's clock being time since boot), the alarm state becomes AlarmConditionType
events emitted by the Server object, and the log is read (read-only, its own thread) for
history (the rope tensions, and the alarm events' rows as HistoryReadEvents). Acknowledge
and the ShelvedStateMachine's methods from a client go in as the station's `Acknowledge`,
`Shelve` and `Unshelve` commands with the client's user name.

The package: `config` (the table, `OpcuaConfig`), `certs` (the server's certificate, the client
trust list, the logins), `history` (the history storage on the log), `face` (the server, its
address space, the values) and `conditions` (the alarm conditions, Acknowledge, shelving).

asyncua is imported only when the face starts (the `opcua` extra); the station's minimal
install imports this package without it.
"""
from __future__ import annotations

from ropemon.station.opcua.certs import (CERT_DAYS, CERT_FILE, KEY_FILE, TrustList, certificate_uri,
                                         ensure_certificate)
from ropemon.station.opcua.conditions import MAX_SHELVE_MIN, SEVERITY, SHELVING_METHODS, SHELVING_STATE_IDS
from ropemon.station.opcua.config import DEFAULT_ENDPOINT, POLICIES, OpcuaConfig, parse_table
from ropemon.station.opcua.face import (NAMESPACE, QUEUE_MAX, UNECE_URI, UNITS, OpcuaFace, OpcuaListener,
                                        unece_unit_id)
from ropemon.station.opcua.history import EVENT_COLUMNS, HISTORY_MAX_VALUES
from ropemon.station.faces import FaceError, StationView
from ropemon.station.stationfile import StationConfigError

__all__ = ["CERT_DAYS", "CERT_FILE", "DEFAULT_ENDPOINT", "EVENT_COLUMNS", "HISTORY_MAX_VALUES", "KEY_FILE",
           "MAX_SHELVE_MIN", "NAMESPACE", "POLICIES", "QUEUE_MAX", "SEVERITY", "SHELVING_METHODS",
           "SHELVING_STATE_IDS", "UNECE_URI", "UNITS", "OpcuaFace", "OpcuaConfig", "OpcuaListener", "TrustList",
           "certificate_uri", "ensure_certificate", "parse_table", "start", "unece_unit_id"]


# -- the face's entry point ------------------------------------------------------------


def start(view: StationView, cfg: OpcuaConfig) -> OpcuaFace:
    """Add the listener to every hoist, start the server (the faces contract, `ropemon.station.faces`)."""
    import importlib.util

    if importlib.util.find_spec("asyncua") is None:
        raise FaceError("[opcua]: the opcua face needs its libraries: pip install 'ropemon[opcua]'")
    users = None
    if cfg.users is not None:
        from ropemon.station.users import Users, UsersError
        try:
            users = Users(cfg.users)
        except (UsersError, OSError) as e:
            raise StationConfigError(f"opcua.users: {e}") from None
    face = OpcuaFace(view, cfg, users)
    try:
        face.start()
    except RuntimeError as e:
        raise FaceError(str(e)) from None
    view.add_listeners(lambda h: OpcuaListener(face, h.id))
    return face
