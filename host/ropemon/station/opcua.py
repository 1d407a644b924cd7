"""The OPC UA face: every hoist's ropes, alarms and history for SCADA (docs/integration.md).

    [opcua]
    endpoint = "opc.tcp://127.0.0.1:4840/ropemon"
    certificates = "opcua-pki"          # server.der and server-key.pem (0600), made on first start
    users = "users.toml"                # who may log in: the web face's users file (`ropemon user add`)
    allow_anonymous = false
    security = ["Basic256Sha256_SignAndEncrypt"]
    trusted_clients = "opcua-pki/trusted"   # optional: only these client certificates (refused ones go to
                                            # opcua-pki/rejected for an engineer to move in)

`start(stations, table)` checks the table (refusing it with the field named), adds an
`OpcuaListener` to every hoist and runs an asyncua server in its own thread with its own
asyncio loop. The listener runs on the station's thread and only hands each message to
that loop (`loop.call_soon_threadsafe`, onto a bounded queue): it never waits for the
server. On the loop, frames become variable values (SourceTimestamp: the frame's receipt
time, the node's clock being time since boot), the alarm state becomes AlarmConditionType
events emitted by the Server object, and the log is read (read-only, its own thread) for
history (the rope tensions, and the alarm events' rows as HistoryReadEvents). Acknowledge
and the ShelvedStateMachine's methods from a client go in as the station's `Acknowledge`,
`Shelve` and `Unshelve` commands with the client's user name.

asyncua is imported only when the face starts (the `opcua` extra); the station's minimal
install imports this module without it.
"""
from __future__ import annotations

import asyncio
import contextvars
import datetime
import logging
import math
import socket
import threading
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

from ropemon.station.tomlfields import Table
from ropemon.station import files
from ropemon.station.alarms import PRIORITY, ActiveAlarm, AlarmEvent
from ropemon.station.link import Received
from ropemon.station.pipeline import Acknowledge, AlarmState, Listener, Shelve, StationStatus, Unshelve
from ropemon.station.protocol import DAN_TO_N, L, Frame
from ropemon.station.scadavalues import POS_ABSENT, standing_of
from ropemon.station.stationfile import StationFileError

log = logging.getLogger(__name__)

NAMESPACE = "urn:ropemon:opcua"
DEFAULT_ENDPOINT = "opc.tcp://127.0.0.1:4840/ropemon"
#: Security policies the table may name (asyncua's SecurityPolicyType members); no "None".
POLICIES = ("Basic256Sha256_SignAndEncrypt", "Basic256Sha256_Sign", "Aes256Sha256RsaPss_SignAndEncrypt",
            "Aes256Sha256RsaPss_Sign", "Aes128Sha256RsaOaep_SignAndEncrypt", "Aes128Sha256RsaOaep_Sign")
CERT_FILE, KEY_FILE = "server.der", "server-key.pem"
CERT_DAYS = 5 * 365
#: OPC UA Severity (1..1000) of each station alarm priority (1 highest).
SEVERITY = {1: 800, 2: 500, 3: 300}
QUEUE_MAX = 50_000          # messages waiting for the server; past it frames are dropped (counted)
HISTORY_MAX_VALUES = 10_000  # values in one history-read answer; a continuation point gives the rest
#: the events columns a history event is made of (`Store.events` rows cut down to them)
EVENT_COLUMNS = ("id", "time_s", "action", "alarm", "kind", "node", "rope", "message", "operator")
MAX_SHELVE_MIN = 720.0       # the longest TimedShelve, and a OneShotShelve's bound (as the web face's)

#: UNECE Rec. 20 codes of the units (OPC UA EUInformation, Part 8).
UNITS = {"kN": ("B47", "kilonewton"), "%": ("P1", "percent"), "m": ("MTR", "metre"), "mm": ("MMT", "millimetre"),
         "m/s": ("MTS", "metre per second"), "V": ("VLT", "volt"), "degC": ("CEL", "degree Celsius")}
UNECE_URI = "http://www.opcfoundation.org/UA/units/un/cefact"


def unece_unit_id(code: str) -> int:
    """The UnitId of a UNECE common code (OPC UA Part 8: its characters as bytes, big-endian)."""
    out = 0
    for c in code:
        out = (out << 8) | ord(c)
    return out


# -- the table ---------------------------------------------------------------------


@dataclass(frozen=True)
class OpcuaFile:
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


def parse_table(data: Any, base: Path) -> OpcuaFile:
    """The [opcua] table, checked; StationFileError names the field."""
    t = Table(data, "opcua", StationFileError)

    def path(key: str, default: str | None) -> Path | None:
        text = t.string(key, default) if (t.has(key) or default is not None) else None
        if text is None:
            return None
        if not text:
            raise StationFileError(f"{t.field(key)}: must not be empty")
        p = Path(text)
        return p if p.is_absolute() else base / p

    endpoint = t.string("endpoint", DEFAULT_ENDPOINT)
    u = urlparse(endpoint)
    try:
        port = u.port
    except ValueError:
        port = -1
    if u.scheme != "opc.tcp" or not u.hostname or (port is not None and not 1 <= port <= 65535):
        raise StationFileError(f"{t.field('endpoint')}: must be opc.tcp://HOST:PORT/PATH, got {endpoint!r}")
    certs = path("certificates", "opcua-pki")
    users = path("users", None)
    anon = t.boolean("allow_anonymous", False)
    sec = t.array("security", ["Basic256Sha256_SignAndEncrypt"], min_len=1, what="security policy names")
    trusted = path("trusted_clients", None)
    for i, s in enumerate(sec):
        if s not in POLICIES:
            raise StationFileError(f"{t.field('security')}[{i}]: must be one of {', '.join(POLICIES)}, got {s!r} "
                                   "(no unencrypted endpoint)")
    t.finish()
    if users is None and not anon:
        raise StationFileError("opcua.users: needed unless allow_anonymous = true (nobody could log in)")
    assert certs is not None
    return OpcuaFile(endpoint, certs, users, anon, tuple(dict.fromkeys(sec)), trusted)


# -- the client trust list -------------------------------------------------------------------


class TrustList:
    """The client certificates the server accepts: the DER or PEM files in the `trusted` folder,
    read again at each check (moving a certificate in or out needs no restart). A certificate is
    trusted when it is one of them, byte for byte, and within its validity period; no CA chains
    and no revocation lists. A refused certificate is written (DER) to the `rejected` folder,
    `<common name> [<SHA-1 thumbprint>].der`, for an engineer to move into `trusted`; at most
    REJECTED_MAX files are kept there."""

    REJECTED_MAX = 200

    def __init__(self, trusted: Path, rejected: Path) -> None:
        self.trusted, self.rejected = trusted, rejected
        trusted.mkdir(parents=True, exist_ok=True)
        rejected.mkdir(parents=True, exist_ok=True)

    def _fingerprints(self) -> set[bytes]:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes
        out = set()
        for f in sorted(self.trusted.iterdir()):
            if not f.is_file() or f.suffix.lower() not in (".der", ".pem", ".crt", ".cer"):
                continue
            try:
                data = f.read_bytes()
                c = (x509.load_pem_x509_certificate(data) if data.lstrip().startswith(b"-----BEGIN")
                     else x509.load_der_x509_certificate(data))
            except (ValueError, OSError) as e:
                log.warning("OPC UA trust list: %s is not a certificate (%s)", f, e)
                continue
            out.add(c.fingerprint(hashes.SHA256()))
        return out

    def why_refused(self, der: bytes | None) -> str | None:
        """None when the certificate (DER) is trusted, else why (and it is written to `rejected`)."""
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes
        if not der:
            return "no client certificate"
        try:
            c = x509.load_der_x509_certificate(bytes(der))
        except ValueError:
            return "not a certificate"
        if c.fingerprint(hashes.SHA256()) not in self._fingerprints():
            self._reject(c)
            return f"certificate {_cert_name(c)!r} is not in {self.trusted}"
        now = datetime.datetime.now(datetime.timezone.utc)
        if not c.not_valid_before_utc <= now <= c.not_valid_after_utc:
            return f"certificate {_cert_name(c)!r} is outside its validity period"
        return None

    def _reject(self, c: Any) -> None:
        from cryptography.hazmat.primitives import hashes
        from cryptography.hazmat.primitives.serialization import Encoding
        name = "".join(ch if ch.isalnum() or ch in " ._-" else "_" for ch in _cert_name(c))[:64].strip() or "client"
        f = self.rejected / f"{name} [{c.fingerprint(hashes.SHA1()).hex().upper()}].der"   # noqa: S303 (OPC UA thumbprint)
        try:
            if f.exists() or sum(1 for _ in self.rejected.iterdir()) >= self.REJECTED_MAX:
                return
            f.write_bytes(c.public_bytes(Encoding.DER))
        except OSError as e:
            log.warning("OPC UA: could not keep the rejected certificate %s: %s", f, e)


def _cert_name(c: Any) -> str:
    from cryptography import x509
    cn = c.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)
    return str(cn[0].value) if cn else c.subject.rfc4514_string()


# -- the listener: the station's thread -> the server's loop -------------------------


class OpcuaListener(Listener):
    """One hoist's messages to the OPC UA server's loop; never waits for it."""

    name = "opcua"

    def __init__(self, face: "OpcuaFace", hoist: str) -> None:
        self.face, self.hoist = face, hoist

    def on_frame(self, item: Received, now_s: float) -> None:
        self.face.post(self.hoist, "frame", item)

    def on_alarms(self, state: AlarmState) -> None:
        self.face.post(self.hoist, "alarms", state)

    def on_status(self, status: StationStatus) -> None:
        self.face.post(self.hoist, "status", status)

    def on_event(self, event: AlarmEvent) -> None:
        if event.action == "refused" and event.operator and event.operator.endswith("(opcua)"):
            log.warning("hoist %s: %s", self.hoist, event.message)

    def health(self) -> str | None:
        return self.face.health()


# -- the model of one hoist -----------------------------------------------------------


@dataclass
class _Rope:
    tension: Any
    raw: Any
    deviation: Any
    dev_min: Any
    dev_max: Any
    area_m2: float | None
    position: Any = None           # piston position, mm from mid-stroke
    near_low: Any = None           # within the stroke margin of the retracted end (Boolean)
    near_high: Any = None          # ... of the extended end


@dataclass
class _Node:
    obj: Any
    ropes: list[_Rope]
    sum: Any
    depth: Any
    speed: Any
    battery: Any
    oil: Any
    status: Any
    fault_mask: Any
    seq: Any
    links: dict[str, Any]          # receiver -> its share of this node's frames (%)
    hidden: Any = None             # the standing status: the imbalance the seals can hide (%)
    standing: Any = None           # ... and its line of text
    standing_last: tuple | None = None   # what was last written to those two


@dataclass
class _Hoist:
    id: str
    obj: Any
    alarms_obj: Any
    nodes: dict[int, _Node]
    receivers: dict[str, Any]      # receiver -> Connected (Boolean)
    db_path: Path | None
    alarms: dict[str, tuple] = None  # type: ignore[assignment]   # alarm id -> lifecycle key last emitted
    conditions: dict[str, Any] = None  # type: ignore[assignment]  # alarm id -> condition NodeId
    views: dict[str, ActiveAlarm] = None  # type: ignore[assignment]
    one_shot: dict[str, list] = None  # type: ignore[assignment]  # alarm id -> [user, seen present, shelved seen]


_CALLER: contextvars.ContextVar[Any] = contextvars.ContextVar("ropemon_opcua_caller", default=None)


class _UserManager:
    """asyncua's user manager on the station's users file (`ropemon.station.users.Users`, the
    web face's: one file, one set of roles): a listed user with the right password, or, with
    allow_anonymous, a client without a name, as a viewer."""

    def __init__(self, users: Any, allow_anonymous: bool, trust: TrustList | None = None) -> None:
        self.users, self.allow_anonymous, self.trust = users, allow_anonymous, trust

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> Any:
        from asyncua.crypto.permission_rules import User, UserRole
        if self.trust is not None:
            # `certificate` is the secure channel's own client certificate: the one CreateSession
            # names (checked by _check_client) could be another's
            why = self.trust.why_refused(certificate)
            if why is not None:
                from asyncua import ua
                from asyncua.common.utils import ServiceError
                log.warning("OPC UA session refused: %s", why)
                raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)
        if username is None and password is None:   # an anonymous token (over a secure channel: with its certificate)
            return User(role=UserRole.User, name=None) if self.allow_anonymous else None
        if self.users is None or not username or password is None:
            return None
        u, why = self.users.login(username, password)
        if u is None:
            log.warning("OPC UA login refused for %r: %s", username, why)
            return None
        return User(role=UserRole.User, name=u.name)


class _History:
    """asyncua's history storage on each hoist's log: ReadRaw of the rope tensions, read from a
    read-only `Store` in its own thread (sqlite connections stay in one thread)."""

    def __init__(self, face: "OpcuaFace") -> None:
        self.face = face
        self.max_history_data_response_size = HISTORY_MAX_VALUES
        self.series: dict[Any, tuple[Path, int, int, str, float | None]] = {}  # NodeId -> db, node, rope, what, area
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="opcua-history")
        self._stores: dict[Path, Any] = {}

    async def init(self) -> None:
        pass

    async def new_historized_node(self, node_id: Any, period: Any, count: int = 0) -> None:
        pass

    async def save_node_value(self, node_id: Any, datavalue: Any) -> None:
        pass

    async def new_historized_event(self, source_id: Any, evtypes: Any, period: Any, count: int = 0) -> None:
        pass

    async def save_event(self, event: Any) -> None:
        pass

    async def read_event_history(self, source_id: Any, start: Any, end: Any, nb_values: int, evfilter: Any):
        """HistoryReadEvents on the Server object (every hoist) or a hoist's object (its own): the
        rows of the hoists' logs' events table, as AlarmConditionType events (EVENT_HISTORY)."""
        from asyncua import ua
        face = self.face
        if source_id == ua.NodeId(ua.ObjectIds.Server):
            hoists = list(face.hoists.values())
        else:
            hoists = [h for h in face.hoists.values() if h.obj == source_id]
        hoists = [h for h in hoists if h.db_path is not None]
        if not hoists:
            return [], None
        span = _span(start, end, nb_values)
        if span is None:
            return [], None
        lo, hi, newest_first, want = span
        rows: list[tuple[str, dict]] = []
        for h in hoists:
            got = await asyncio.get_running_loop().run_in_executor(
                self._pool, self._event_rows, h.db_path, lo, hi, want + 1, newest_first)
            rows += [(h.id, r) for r in got]
        rows.sort(key=lambda x: (x[1]["time_s"], x[0], x[1]["id"]), reverse=newest_first)
        cont = None
        if len(rows) > want and not (nb_values and nb_values <= HISTORY_MAX_VALUES):
            cont = _utc(rows[want][1]["time_s"])
        return [face._history_event(face.hoists[hid], r) for hid, r in rows[:want]], cont

    def _event_rows(self, db: Path, lo: float | None, hi: float | None, limit: int, newest_first: bool) -> list:
        store = self._open(db)
        if store is None:
            return []
        rows = store.events(since=lo, until=hi, by_time=True, newest_first=newest_first, limit=limit)
        return [{c: r[c] for c in EVENT_COLUMNS if c in r} for r in rows]

    async def stop(self) -> None:
        self._pool.submit(self._close).result()
        self._pool.shutdown()

    def _close(self) -> None:
        for s in self._stores.values():
            s.close()
        self._stores.clear()

    async def read_node_history(self, node_id: Any, start: Any, end: Any, nb_values: int):
        spec = self.series.get(node_id)
        if spec is None:
            return [], None
        span = _span(start, end, nb_values)
        if span is None:
            return [], None
        lo, hi, newest_first, want = span
        rows = await asyncio.get_running_loop().run_in_executor(
            self._pool, self._query, spec, lo, hi, want + 1, newest_first)
        cont = None
        if len(rows) > want and not (nb_values and nb_values <= HISTORY_MAX_VALUES):
            cont = _utc(rows[want][0])
        rows = rows[:want]
        _, _, _, what, area = spec
        return [_history_value(what, area, rx, mean, raw) for rx, mean, raw in rows], cont

    def _open(self, db: Path) -> Any:
        from ropemon.station.store import Store, StoreError
        store = self._stores.get(db)
        if store is None:
            if not db.exists():
                return None
            try:
                store = self._stores[db] = Store(db, readonly=True)
            except StoreError as e:
                log.warning("history: %s", e)
                return None
        return store

    def _query(self, spec: tuple, lo: float | None, hi: float | None, limit: int, newest_first: bool) -> list:
        db, node, rope, _, _ = spec
        store = self._open(db)
        if store is None:
            return []
        return store.rope_series(node, rope, lo, hi, limit, newest_first)


def _span(start: Any, end: Any, nb_values: int) -> tuple[float | None, float | None, bool, int] | None:
    """A history read's (lo, hi, newest first, how many) from OPC UA's start, end and count
    (an unset time is the Windows epoch); None when neither time is set (nothing to read)."""
    from asyncua import ua
    epoch = ua.get_win_epoch()
    t0 = None if start is None or start == epoch else start.timestamp()
    t1 = None if end is None or end == epoch else end.timestamp()
    if t0 is None and t1 is None:
        return None
    newest_first = t0 is None or (t1 is not None and t0 > t1)
    lo, hi = (t1, t0) if (t0 is not None and t1 is not None and t0 > t1) else (t0, t1)
    return lo, hi, newest_first, min(nb_values or HISTORY_MAX_VALUES, HISTORY_MAX_VALUES)


def _utc(t: float) -> datetime.datetime:
    return datetime.datetime.fromtimestamp(t, datetime.timezone.utc)


def _history_value(what: str, area: float | None, rx: float, mean_dan: int, raw_kpa: int) -> Any:
    from asyncua import ua
    ts = _utc(rx)
    if what == "Tension":
        v = None if mean_dan == L.TENSION_ABSENT else mean_dan * DAN_TO_N / 1000.0
    else:
        v = None if raw_kpa == L.RAW_KPA_ABSENT or area is None else raw_kpa * area
    if v is None:
        return ua.DataValue(StatusCode=ua.StatusCode(ua.StatusCodes.BadSensorFailure), SourceTimestamp=ts,
                            ServerTimestamp=ts)
    return ua.DataValue(ua.Variant(v, ua.VariantType.Double), SourceTimestamp=ts, ServerTimestamp=ts)


# -- the face ------------------------------------------------------------------------


class OpcuaFace:
    """The asyncua server in its own thread and loop, fed by one `OpcuaListener` per hoist."""

    def __init__(self, stations: Any, cfg: OpcuaFile, users: Any = None) -> None:
        self.stations, self.cfg, self.users = stations, cfg, users
        self.loop = asyncio.new_event_loop()
        self.queue: asyncio.Queue | None = None
        self.dropped = 0
        self.error: str | None = None
        self.server: Any = None
        self.hoists: dict[str, _Hoist] = {}
        self.by_condition: dict[Any, tuple[str, str]] = {}   # condition NodeId -> (hoist, alarm id)
        self.by_shelving: dict[Any, tuple[str, str]] = {}    # its ShelvingState NodeId -> (hoist, alarm id)
        self.event_ids: dict[bytes, tuple[str, str]] = {}    # EventIds sent -> (hoist, alarm id)
        self.idx = 2
        self.app_uri = ""
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._thread = threading.Thread(target=self._run, name="opcua", daemon=True)
        self._stopping = False
        self.notified = 0      # values written

    # -- the station's side (any thread) --------------------------------------------------

    def post(self, hoist: str, kind: str, msg: Any) -> None:
        if self.queue is None or self.loop.is_closed():
            return
        try:
            self.loop.call_soon_threadsafe(self._put, (hoist, kind, msg))
        except RuntimeError:     # the loop closed meanwhile
            pass

    def _put(self, item: tuple) -> None:
        assert self.queue is not None
        try:
            self.queue.put_nowait(item)
        except asyncio.QueueFull:
            self.dropped += 1

    def health(self) -> str | None:
        if self.error is not None:
            return f"OPC UA server failed: {self.error}"
        if self._ready.is_set() and not self._thread.is_alive() and not self._stopping:
            return "OPC UA server stopped"
        return None

    def start(self, timeout_s: float = 60.0) -> None:
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise RuntimeError(f"[opcua]: the server did not start within {timeout_s:.0f} s")
        if self.error is not None:
            self._thread.join(5)
            raise RuntimeError(f"[opcua]: {self.error}")

    def stop(self) -> None:
        self._stopping = True
        if self._stop is not None and self._thread.is_alive():
            self.loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(30)

    def describe(self) -> str:
        who = "users from " + str(self.cfg.users) if self.cfg.users else "no users file"
        anon = ", anonymous allowed" if self.cfg.allow_anonymous else ""
        trust = (f"client certificates from {self.cfg.trusted_clients} only" if self.cfg.trusted_clients
                 else "any client certificate")
        return (f"OPC UA on {self.cfg.endpoint} ({', '.join(self.cfg.security)}; {who}{anon}; {trust}; "
                f"certificate {self.cfg.certificates / CERT_FILE})")

    # -- the server's thread ----------------------------------------------------------------

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self.loop.run_until_complete(self._serve())
        except BaseException as e:   # reported through health() and start()
            self.error = f"{type(e).__name__}: {e}"
            log.exception("OPC UA server failed")
        finally:
            self._ready.set()
            try:
                self.loop.run_until_complete(self.loop.shutdown_asyncgens())
            finally:
                self.loop.close()

    async def _serve(self) -> None:
        from asyncua import Server, ua

        self.queue = asyncio.Queue(QUEUE_MAX)
        self._stop = asyncio.Event()
        cert, key = await asyncio.to_thread(ensure_certificate, self.cfg.certificates, self.cfg.host_port[0])
        self.app_uri = certificate_uri(cert) or f"urn:ropemon:station:{socket.gethostname()}"
        trust = None
        if self.cfg.trusted_clients is not None:
            assert self.cfg.rejected_clients is not None
            trust = TrustList(self.cfg.trusted_clients, self.cfg.rejected_clients)
        server = Server(user_manager=_UserManager(self.users, self.cfg.allow_anonymous, trust))
        server.iserver.bind_condition_methods = True        # ConditionRefresh
        self.history = _History(self)
        server.iserver.history_manager.set_storage(self.history)
        await server.init()
        server.set_endpoint(self.cfg.endpoint)
        server.set_server_name(f"ropemon station {self.stations.file.name}")
        await server.set_application_uri(self.app_uri)
        server.product_uri = "urn:ropemon"
        server.manufacturer_name = "ropemon"
        await server.load_certificate(str(cert))
        await server.load_private_key(str(key))
        server.set_security_policy([getattr(ua.SecurityPolicyType, p) for p in self.cfg.security])
        tokens: list[type] = [ua.UserNameIdentityToken]
        if self.cfg.allow_anonymous:
            tokens.insert(0, ua.AnonymousIdentityToken)
        server.set_identity_tokens(tokens)
        if trust is not None:
            server.set_certificate_validator(_certificate_check(trust))
        self._track_callers(server)
        self.server = server
        self.idx = await server.register_namespace(NAMESPACE)
        await self._build(server)
        server.link_method(server.get_node(ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)),
                           self._acknowledge)
        for how, names in SHELVING_METHODS.items():
            for name in names:
                mid = ua.NodeId(getattr(ua.ObjectIds, name))
                if mid in server.iserver.aspace:      # asyncua 2.1's address space lacks some "2" forms
                    server.link_method(server.get_node(mid), self._shelving(how))
        await server.start()
        consumer = asyncio.create_task(self._consume())
        self._ready.set()
        try:
            await self._stop.wait()
        finally:
            consumer.cancel()
            await server.stop()

    @staticmethod
    def _track_callers(server: Any) -> None:
        """Each session's method calls run with its user in `_CALLER` (asyncua passes a method
        only the object and the arguments, not who calls)."""
        iserver = server.iserver
        make = iserver.create_session

        def create_session(*args: Any, **kw: Any) -> Any:
            s = make(*args, **kw)
            call = s.call

            async def call_as(params: Any) -> Any:
                token = _CALLER.set(s.user)
                try:
                    return await call(params)
                finally:
                    _CALLER.reset(token)
            s.call = call_as
            return s
        iserver.create_session = create_session

    # -- the address space --------------------------------------------------------------

    def _nid(self, text: str) -> Any:
        from asyncua import ua
        return ua.NodeId(text, self.idx)

    async def _object(self, parent: Any, sid: str, name: str, display: str | None = None,
                      typedef: Any = None, folder: bool = False) -> Any:
        from asyncua import ua
        item = ua.AddNodesItem()
        item.RequestedNewNodeId = self._nid(sid)
        item.BrowseName = ua.QualifiedName(name, self.idx)
        item.NodeClass = ua.NodeClass.Object
        item.ParentNodeId = parent
        item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.Organizes if folder else ua.ObjectIds.HasComponent)
        item.TypeDefinition = ua.NodeId(ua.ObjectIds.FolderType) if folder else (
            typedef or ua.NodeId(ua.ObjectIds.BaseObjectType))
        attrs = ua.ObjectAttributes()
        attrs.DisplayName = ua.LocalizedText(display or name)
        attrs.Description = ua.LocalizedText(display or name)
        attrs.EventNotifier = 0
        item.NodeAttributes = attrs
        (res,) = await self.server.iserver.isession.add_nodes([item])
        res.StatusCode.check()
        return res.AddedNodeId

    async def _variable(self, parent: Any, sid: str, name: str, vtype: str, unit: str | None = None,
                        eu_range: tuple[float, float] | None = None, history: bool = False,
                        description: str = "") -> Any:
        from asyncua import ua
        vt = getattr(ua.VariantType, vtype)
        item = ua.AddNodesItem()
        nid = self._nid(sid)
        item.RequestedNewNodeId = nid
        item.BrowseName = ua.QualifiedName(name, self.idx)
        item.NodeClass = ua.NodeClass.Variable
        item.ParentNodeId = parent
        item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasComponent)
        analog = unit is not None
        item.TypeDefinition = ua.NodeId(ua.ObjectIds.AnalogItemType if analog else ua.ObjectIds.BaseDataVariableType)
        attrs = ua.VariableAttributes()
        attrs.DisplayName = ua.LocalizedText(name)
        attrs.Description = ua.LocalizedText(description or name)
        attrs.DataType = ua.NodeId(vt.value)
        attrs.ValueRank = ua.ValueRank.Scalar
        level = ua.AccessLevel.CurrentRead.mask | (ua.AccessLevel.HistoryRead.mask if history else 0)
        attrs.AccessLevel = attrs.UserAccessLevel = level
        attrs.Historizing = history
        item.NodeAttributes = attrs
        (res,) = await self.server.iserver.isession.add_nodes([item])
        res.StatusCode.check()
        node = self.server.get_node(nid)
        await self.server.write_attribute_value(
            nid, ua.DataValue(StatusCode=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData)))
        if analog:
            code, desc = UNITS[unit]
            eu = ua.EUInformation(NamespaceUri=UNECE_URI, UnitId=unece_unit_id(code),
                                  DisplayName=ua.LocalizedText(unit if unit != "degC" else "\u00b0C"),
                                  Description=ua.LocalizedText(desc))
            await node.add_property(self._nid(sid + ".EngineeringUnits"), ua.QualifiedName("EngineeringUnits", 0),
                                    ua.Variant(eu, ua.VariantType.ExtensionObject),
                                    datatype=ua.NodeId(ua.ObjectIds.EUInformation))
            lo, hi = eu_range if eu_range is not None else (-math.inf, math.inf)
            await node.add_property(self._nid(sid + ".EURange"), ua.QualifiedName("EURange", 0),
                                    ua.Variant(ua.Range(Low=lo, High=hi), ua.VariantType.ExtensionObject),
                                    datatype=ua.NodeId(ua.ObjectIds.Range))
        return nid

    async def _build(self, server: Any) -> None:
        from asyncua import ua
        root = await self._object(ua.NodeId(ua.ObjectIds.ObjectsFolder), "ropemon", "Ropemon",
                                  f"ropemon: {self.stations.file.name}", folder=True)
        for h in self.stations.hoists.values():
            ranges = _ranges(h)
            hid = h.id
            hobj = await self._object(root, hid, hid, h.name)
            alarms_obj = await self._object(hobj, f"{hid}.Alarms", "Alarms", f"{h.name}: alarm conditions",
                                            folder=True)
            receivers = {}
            rx_folder = await self._object(hobj, f"{hid}.Receivers", "Receivers", folder=True)
            rx_names = [name for name, _ in (h.spec.receivers if h.spec is not None else ())]
            for name in rx_names:
                robj = await self._object(rx_folder, f"{hid}.Receivers.{name}", name)
                receivers[name] = await self._variable(robj, f"{hid}.Receivers.{name}.Connected", "Connected",
                                                       "Boolean", description="the receiver's port is open")
            nodes = {}
            areas = list(h.site.cylinder_area_m2)
            strokes = list(getattr(h.site, "stroke_m", None) or ())
            for n in sorted(h.keys):
                base = f"{hid}.n{n}"
                nobj = await self._object(hobj, base, f"Node{n}", f"{h.name}: node {n}")
                ropes = []
                for k in range(len(areas)):
                    rb = f"{base}.r{k + 1}"
                    robj = await self._object(nobj, rb, f"Rope{k + 1}", f"{h.name}: node {n} rope {k + 1}")
                    rng = ranges[k] if k < len(ranges) else None
                    r = _Rope(
                        await self._variable(robj, f"{rb}.Tension", "Tension", "Double", "kN", rng, history=True,
                                             description="compensated rope tension (window mean)"),
                        await self._variable(robj, f"{rb}.RawTension", "RawTension", "Double", "kN", rng,
                                             history=True, description="tap pressure x cylinder area, uncompensated"),
                        await self._variable(robj, f"{rb}.Deviation", "Deviation", "Double", "%", (-100.0, 100.0),
                                             description="from the mean of the ropes present"),
                        await self._variable(robj, f"{rb}.DeviationMin", "DeviationMin", "Double", "%",
                                             (-100.0, 100.0), description="low end of the deviation's band"),
                        await self._variable(robj, f"{rb}.DeviationMax", "DeviationMax", "Double", "%",
                                             (-100.0, 100.0), description="high end of the deviation's band"),
                        areas[k])
                    half = strokes[k] / 2 * 1000.0 if k < len(strokes) and strokes[k] else None
                    r.position = await self._variable(
                        robj, f"{rb}.Position", "Position", "Double", "mm", (-half, half) if half else None,
                        description="piston position from mid-stroke (window mean; > 0: pulled out by the rope); "
                                    "EURange: the end stops")
                    r.near_low = await self._variable(
                        robj, f"{rb}.NearRetractedEnd", "NearRetractedEnd", "Boolean",
                        description="the piston came within the stroke margin of its retracted end in the window")
                    r.near_high = await self._variable(
                        robj, f"{rb}.NearExtendedEnd", "NearExtendedEnd", "Boolean",
                        description="the piston came within the stroke margin of its extended end in the window")
                    ropes.append(r)
                    if h.db_path is not None:
                        self.history.series[r.tension] = (h.db_path, n, k, "Tension", None)
                        self.history.series[r.raw] = (h.db_path, n, k, "RawTension", areas[k])
                total = (0.0, ranges[0][1] * len(areas)) if ranges else None
                links = {}
                lobj = await self._object(nobj, f"{base}.LinkQuality", "LinkQuality", folder=True)
                for name in rx_names:
                    links[name] = await self._variable(lobj, f"{base}.LinkQuality.{name}", name, "Double", "%",
                                                       (0.0, 100.0), description="share of this node's frames "
                                                       "delivered by this receiver")
                nodes[n] = _Node(
                    nobj, ropes,
                    await self._variable(nobj, f"{base}.Sum", "Sum", "Double", "kN", total,
                                         description="sum of the rope tensions"),
                    await self._variable(nobj, f"{base}.Depth", "Depth", "Double", "m"),
                    await self._variable(nobj, f"{base}.Speed", "Speed", "Double", "m/s"),
                    await self._variable(nobj, f"{base}.Battery", "Battery", "Double", "V", (0.0, 65.535)),
                    await self._variable(nobj, f"{base}.OilTemperature", "OilTemperature", "Double", "degC",
                                         (-40.0, 150.0)),
                    await self._variable(nobj, f"{base}.Status", "Status", "UInt16",
                                         description="status bits (docs/protocol.md)"),
                    await self._variable(nobj, f"{base}.FaultMask", "FaultMask", "Byte",
                                         description="pressure/displacement channels failed (docs/protocol.md)"),
                    await self._variable(nobj, f"{base}.Seq", "Seq", "UInt32",
                                         description="the frame's sequence number"),
                    links,
                    await self._variable(nobj, f"{base}.HiddenImbalance", "HiddenImbalance", "Double", "%",
                                         (0.0, 100.0), description="standing status: the imbalance (of the mean "
                                         "rope tension) the seals' static friction can hide with the ropes equal"),
                    await self._variable(nobj, f"{base}.StandingStatus", "StandingStatus", "String",
                                         description="standing status: one line an operator reads"))
            self.hoists[hid] = _Hoist(hid, hobj, alarms_obj, nodes, receivers, h.db_path, {}, {}, {}, {})
        # the Server object emits the alarm conditions' events
        await server.get_node(ua.NodeId(ua.ObjectIds.Server)).set_event_notifier(
            [ua.EventNotifier.SubscribeToEvents, ua.EventNotifier.HistoryRead])
        for h in self.hoists.values():     # a hoist's own event history (no live events there)
            if h.db_path is not None:
                await server.get_node(h.obj).set_event_notifier([ua.EventNotifier.HistoryRead])

    # -- values -----------------------------------------------------------------------

    async def _consume(self) -> None:
        assert self.queue is not None
        while True:
            hoist, kind, msg = await self.queue.get()
            h = self.hoists.get(hoist)
            if h is None:
                continue
            try:
                if kind == "frame":
                    await self._frame(h, msg)
                elif kind == "alarms":
                    await self._alarms(h, msg)
                elif kind == "status":
                    await self._status(h, msg)
            except Exception:  # one bad message must not stop the face
                log.exception("OPC UA: hoist %s, %s", hoist, kind)

    async def _write(self, nid: Any, value: Any, vtype: Any, ts: datetime.datetime, bad: int | None = None) -> None:
        from asyncua import ua
        if value is None:
            dv = ua.DataValue(StatusCode=ua.StatusCode(bad or ua.StatusCodes.BadSensorFailure), SourceTimestamp=ts)
        else:
            dv = ua.DataValue(ua.Variant(value, vtype), SourceTimestamp=ts)
        await self.server.iserver.aspace.write_attribute_value(nid, ua.AttributeIds.Value, dv)
        self.notified += 1

    async def _frame(self, h: _Hoist, item: Received) -> None:
        from asyncua import ua
        f: Frame = item.frame
        n = h.nodes.get(f.node)
        if n is None:
            return
        ts = _utc(item.rx_time)
        D = ua.VariantType.Double
        present = [r.mean_dan for r in f.ropes if r.mean_dan != L.TENSION_ABSENT]
        mean = sum(present) / len(present) if present else 0.0
        for k, rope in enumerate(n.ropes):
            r = f.ropes[k] if k < len(f.ropes) else None
            t = None if r is None or r.mean_dan == L.TENSION_ABSENT else r.mean_dan * DAN_TO_N / 1000.0
            raw = (None if r is None or r.raw_kpa == L.RAW_KPA_ABSENT or rope.area_m2 is None
                   else r.raw_kpa * rope.area_m2)
            await self._write(rope.tension, t, D, ts)
            await self._write(rope.raw, raw, D, ts)
            dev = (r.mean_dan - mean) / mean * 100.0 if (t is not None and len(present) >= 2 and mean > 0) else None
            await self._write(rope.deviation, dev, D, ts, ua.StatusCodes.BadNoData if t is not None else None)
            if f.version < 3 or r is None:       # a version 2 node sends no position
                for nid in (rope.position, rope.near_low, rope.near_high):
                    await self._write(nid, None, D, ts, ua.StatusCodes.BadNoData)
                continue
            pos = getattr(r, "pos_01mm", POS_ABSENT)
            await self._write(rope.position, None if pos == POS_ABSENT else pos / 10.0, D, ts)
            mask = getattr(f, "stroke_mask", 0)
            await self._write(rope.near_low, bool(mask >> k & 1), ua.VariantType.Boolean, ts)
            await self._write(rope.near_high, bool(mask >> (4 + k) & 1), ua.VariantType.Boolean, ts)
        total = f.total_dan
        await self._write(n.sum, None if total is None else total * DAN_TO_N / 1000.0, D, ts)
        await self._write(n.depth, f.depth_mm / 1000.0, D, ts)
        await self._write(n.speed, f.speed_mm_s / 1000.0, D, ts)
        await self._write(n.battery, f.battery_mv / 1000.0, D, ts)
        oil = f.oil_temp_c
        await self._write(n.oil, oil, D, ts, ua.StatusCodes.BadNoData)
        await self._write(n.status, f.status, ua.VariantType.UInt16, ts)
        await self._write(n.fault_mask, f.fault_mask, ua.VariantType.Byte, ts)
        await self._write(n.seq, f.seq, ua.VariantType.UInt32, ts)

    async def _status(self, h: _Hoist, status: StationStatus) -> None:
        from asyncua import ua
        ts = _utc(time.time())
        for name, nid in h.receivers.items():
            r = status.receivers.get(name)
            if r is not None:
                await self._write(nid, bool(r.connected), ua.VariantType.Boolean, ts)
        for node, st in status.merge.items():
            n = h.nodes.get(node)
            if n is None:
                continue
            for name, nid in n.links.items():
                share = st.get("receivers", {}).get(name)
                if share is not None and share.get("share") is not None:
                    await self._write(nid, float(share["share"]) * 100.0, ua.VariantType.Double, ts)

    # -- alarms -----------------------------------------------------------------------

    async def _alarms(self, h: _Hoist, state: AlarmState) -> None:
        from asyncua import ua
        ts = _utc(time.time())
        D = ua.VariantType.Double
        for node, bands in state.bands.items():
            n = h.nodes.get(node)
            if n is None:
                continue
            for k, rope in enumerate(n.ropes):
                b = bands[k] if k < len(bands) else None
                await self._write(rope.dev_min, None if b is None else b.d_min * 100.0, D, ts, ua.StatusCodes.BadNoData)
                await self._write(rope.dev_max, None if b is None else b.d_max * 100.0, D, ts, ua.StatusCodes.BadNoData)
        statuses = getattr(state, "hoist", None) or {}
        for node, n in h.nodes.items():
            st = standing_of(statuses.get(node))
            now_st = (None if st.hidden_frac is None else round(st.hidden_frac * 100.0, 3), st.text)
            if now_st != n.standing_last:
                n.standing_last = now_st
                await self._write(n.hidden, now_st[0], D, ts, ua.StatusCodes.BadNoData)
                await self._write(n.standing, now_st[1], ua.VariantType.String, ts, ua.StatusCodes.BadNoData)
        now = {a.id: a for a in state.active}
        hidden = {a.id: a for a in state.hidden}
        views = {**hidden, **now}
        for aid, a in views.items():
            key = (a.state, a.present, a.latched, a.priority, aid in now)
            if h.alarms.get(aid) != key:
                h.alarms[aid] = key
                await self._emit(h, a, retain=aid in now or a.present, ts=ts, now_s=state.time_s)
        for aid in [x for x in h.alarms if x not in views]:
            del h.alarms[aid]
            last = h.views.pop(aid, None)
            if last is not None:   # back to normal and acknowledged: the condition's last event
                await self._emit(h, last, retain=False, ts=ts, normal=True)
        h.views.update(views)
        await self._one_shot(h, views)

    async def _one_shot(self, h: _Hoist, views: dict[str, ActiveAlarm]) -> None:
        """A OneShotShelve ends when its alarm returns to normal: the face unshelves it then."""
        for aid, entry in list(h.one_shot.items()):
            user, seen, shelved = entry
            a = views.get(aid)
            if a is not None and a.state == "shelved":
                entry[2] = shelved = True
            elif shelved:            # unshelved meanwhile (expired, the terminal, the web, Unshelve)
                del h.one_shot[aid]
                continue
            if not shelved or a is None:
                continue
            if a.present:
                entry[1] = True
            elif seen:
                del h.one_shot[aid]
                self.stations.submit(h.id, Unshelve(user, "opcua one-shot", alarm=aid))

    async def _condition(self, h: _Hoist, aid: str) -> Any:
        from asyncua import ua
        nid = h.conditions.get(aid)
        if nid is None:
            nid = await self._object(h.alarms_obj, f"{h.id}.Alarms.{aid}", aid, f"{h.id}: {aid}",
                                     typedef=ua.NodeId(ua.ObjectIds.AlarmConditionType))
            h.conditions[aid] = nid
            self.by_condition[nid] = (h.id, aid)
            sid = f"{h.id}.Alarms.{aid}.ShelvingState"
            shelving = await self._object(nid, sid, "ShelvingState", f"{h.id}: {aid}: shelving",
                                          typedef=ua.NodeId(ua.ObjectIds.ShelvedStateMachineType))
            refs = []
            for names in SHELVING_METHODS.values():
                for name in names[:2]:       # the ShelvedStateMachineType's methods, shared
                    if ua.NodeId(getattr(ua.ObjectIds, name)) not in self.server.iserver.aspace:
                        continue
                    ref = ua.AddReferencesItem()
                    ref.SourceNodeId = shelving
                    ref.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasComponent)
                    ref.IsForward = True
                    ref.TargetNodeId = ua.NodeId(getattr(ua.ObjectIds, name))
                    ref.TargetNodeClass = ua.NodeClass.Method
                    refs.append(ref)
            for r in await self.server.iserver.isession.add_references(refs):
                r.check()
            await self.server.get_node(nid).add_property(
                self._nid(f"{h.id}.Alarms.{aid}.MaxTimeShelved"), ua.QualifiedName("MaxTimeShelved", 0),
                ua.Variant(MAX_SHELVE_MIN * 60_000.0, ua.VariantType.Double), datatype=ua.NodeId(ua.ObjectIds.Duration))
            self.by_shelving[shelving] = (h.id, aid)
        return nid

    def _source(self, h: _Hoist, a: ActiveAlarm) -> Any:
        n = h.nodes.get(a.node) if a.node is not None else None
        if n is None:
            return h.obj
        if a.rope is not None and 0 <= a.rope < len(n.ropes):
            return self._nid(f"{h.id}.n{a.node}.r{a.rope + 1}")
        return n.obj

    async def _emit(self, h: _Hoist, a: ActiveAlarm, retain: bool, ts: datetime.datetime,
                    normal: bool = False, now_s: float | None = None) -> None:
        from asyncua import ua
        from asyncua.common.event_objects import AlarmCondition
        cid = await self._condition(h, a.id)
        ev = AlarmCondition()
        ev.emitting_node = ua.NodeId(ua.ObjectIds.Server)
        ev.SourceNode = self._source(h, a)
        ev.SourceName = f"{h.id}/{a.id}"
        ev.ConditionName = a.id
        ev.add_property("NodeId", cid, ua.VariantType.NodeId)     # the ConditionId
        ev.BranchId = ua.NodeId()
        severity = SEVERITY.get(a.priority, 300)
        ev.Severity = severity
        ev.LastSeverity = severity
        active = a.present and not normal
        acked = normal or not a.latched
        ev.Retain = retain
        ev.EnabledState = ua.LocalizedText("Enabled")
        setattr(ev, "EnabledState/Id", True)
        ev.ActiveState = ua.LocalizedText("Active" if active else "Inactive")
        setattr(ev, "ActiveState/Id", active)
        ev.AckedState = ua.LocalizedText("Acknowledged" if acked else "Unacknowledged")
        setattr(ev, "AckedState/Id", acked)
        ev.ConfirmedState = ua.LocalizedText("Confirmed")
        setattr(ev, "ConfirmedState/Id", True)
        suppressed = a.state == "suppressed"
        ev.SuppressedState = ua.LocalizedText("Suppressed" if suppressed else "Unsuppressed")
        setattr(ev, "SuppressedState/Id", suppressed)
        shelved = a.state == "shelved" and not normal
        shelf = ("OneShotShelved" if a.id in h.one_shot else "TimedShelved") if shelved else "Unshelved"
        ev.add_property("ShelvingState/CurrentState", ua.LocalizedText(shelf), ua.VariantType.LocalizedText)
        ev.add_property("ShelvingState/CurrentState/Id", ua.NodeId(SHELVING_STATE_IDS[shelf]),
                        ua.VariantType.NodeId)
        left = (max(0.0, (a.shelved_until - now_s) * 1000.0)
                if shelved and a.shelved_until is not None and now_s is not None else 0.0)
        ev.add_property("ShelvingState/UnshelveTime", left, ua.VariantType.Double)
        ev.add_property("MaxTimeShelved", MAX_SHELVE_MIN * 60_000.0, ua.VariantType.Double)   # a Duration (ms)
        oos = a.state == "out_of_service"
        ev.OutOfServiceState = ua.LocalizedText("Out of service" if oos else "In service")
        setattr(ev, "OutOfServiceState/Id", oos)
        ev.SuppressedOrShelved = suppressed or shelved or oos
        ev.Quality = ua.StatusCode(ua.StatusCodes.Good)
        ev.ClientUserId = a.acked_by or ""
        if a.acked_by:
            ev.Comment = ua.LocalizedText(f"acknowledged by {a.acked_by}")
        state = "normal" if normal else a.state
        ev.Message = ua.LocalizedText(f"{a.message} [{state}]" + (f" ({a.note})" if a.note else ""))
        ev.EventId = uuid.uuid4().bytes
        ev.Time = ts
        ev.ReceiveTime = ts
        self.event_ids[ev.EventId] = (h.id, a.id)
        if len(self.event_ids) > 100_000:
            for k in list(self.event_ids)[:50_000]:
                del self.event_ids[k]
        await self.server.iserver.subscription_service.trigger_event(ev)

    def _history_event(self, h: _Hoist, row: dict) -> Any:
        """One row of a hoist's events table as an AlarmConditionType event (EVENT_HISTORY)."""
        from asyncua import ua
        from asyncua.common.event_objects import AlarmCondition
        ev = AlarmCondition()
        ev.EventId = f"{h.id}:log:{row['id']}".encode()
        ts = _utc(row["time_s"])
        ev.Time = ev.ReceiveTime = ts
        aid = row.get("alarm") or ""
        node, rope = row.get("node"), row.get("rope")
        n = h.nodes.get(node) if node is not None else None
        if n is None:
            ev.SourceNode = h.obj
        elif rope is not None and 0 <= rope < len(n.ropes):
            ev.SourceNode = self._nid(f"{h.id}.n{node}.r{rope + 1}")
        else:
            ev.SourceNode = n.obj
        ev.SourceName = f"{h.id}/{aid}" if aid else h.id
        ev.ConditionName = aid
        cid = h.conditions.get(aid)
        ev.add_property("NodeId", cid if cid is not None else ua.NodeId(), ua.VariantType.NodeId)
        ev.Severity = ev.LastSeverity = SEVERITY.get(PRIORITY.get(row.get("kind") or "", 1), 300)
        action = row.get("action") or ""
        ev.Message = ua.LocalizedText(f"{action}: {row.get('message') or ''}")
        ev.ClientUserId = row.get("operator") or ""
        ev.Comment = ua.LocalizedText(action)
        if action in ("raise", "clear"):
            ev.ActiveState = ua.LocalizedText("Active" if action == "raise" else "Inactive")
            setattr(ev, "ActiveState/Id", action == "raise")
        if action in ("raise", "ack"):
            ev.AckedState = ua.LocalizedText("Acknowledged" if action == "ack" else "Unacknowledged")
            setattr(ev, "AckedState/Id", action == "ack")
        ev.Retain = False
        return ev

    async def _acknowledge(self, parent: Any, *args: Any) -> Any:
        """AcknowledgeableConditionType.Acknowledge(EventId, Comment) called on a condition:
        the station's Acknowledge command, with the caller's user name."""
        from asyncua import ua
        target = self.by_condition.get(parent)
        if target is None:
            return ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown)
        if len(args) < 1:
            return ua.StatusCode(ua.StatusCodes.BadArgumentsMissing)
        event_id = args[0].Value if isinstance(args[0], ua.Variant) else args[0]
        if self.event_ids.get(bytes(event_id or b"")) != target:
            return ua.StatusCode(ua.StatusCodes.BadEventIdUnknown)
        name = getattr(_CALLER.get(), "name", None)
        u = self.users.get(name) if (self.users is not None and name) else None
        if u is None or not u.may("ack"):      # anonymous, a viewer, or a user removed from the file
            return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
        hoist, aid = target
        h = self.hoists[hoist]
        key = h.alarms.get(aid)
        if key is None or not key[2]:
            return ua.StatusCode(ua.StatusCodes.BadConditionBranchAlreadyAcked)
        self.stations.submit(hoist, Acknowledge(u.name, "opcua", alarm=aid))
        return ua.StatusCode()

    def _shelving(self, how: str) -> Any:
        async def call(parent: Any, *args: Any) -> Any:
            return await self._shelve(how, parent, *args)
        return call

    async def _shelve(self, how: str, parent: Any, *args: Any) -> Any:
        """ShelvedStateMachineType.TimedShelve(ShelvingTime ms) / OneShotShelve() / Unshelve(), and
        their "2" forms with a Comment, called on a condition's ShelvingState (or the condition):
        the station's Shelve / Unshelve commands with the caller's user name."""
        from asyncua import ua
        target = self.by_shelving.get(parent) or self.by_condition.get(parent)
        if target is None:
            return ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown)
        name = getattr(_CALLER.get(), "name", None)
        u = self.users.get(name) if (self.users is not None and name) else None
        if u is None or not u.may("unshelve" if how == "unshelve" else "shelve"):
            return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
        hoist, aid = target
        h = self.hoists[hoist]
        key = h.alarms.get(aid)
        shelved = key is not None and key[0] == "shelved"
        comment = ""
        texts = args[1:] if how == "timed" else args
        if texts:
            c = _arg(texts[0])
            comment = (c.Text if isinstance(c, ua.LocalizedText) else str(c or "")) or ""
            comment = comment.strip()[:200]
        if how == "unshelve":
            if not shelved:
                return ua.StatusCode(ua.StatusCodes.BadConditionNotShelved)
            h.one_shot.pop(aid, None)
            self.stations.submit(hoist, Unshelve(u.name, "opcua", alarm=aid))
            return ua.StatusCode()
        if how == "timed":
            if not args:
                return ua.StatusCode(ua.StatusCodes.BadArgumentsMissing)
            try:
                ms = float(_arg(args[0]))
            except (TypeError, ValueError):
                return ua.StatusCode(ua.StatusCodes.BadTypeMismatch)
            if not (math.isfinite(ms) and 0 < ms <= MAX_SHELVE_MIN * 60_000.0):
                return ua.StatusCode(ua.StatusCodes.BadShelvingTimeOutOfRange)
            if shelved and aid not in h.one_shot:
                return ua.StatusCode(ua.StatusCodes.BadConditionAlreadyShelved)
            h.one_shot.pop(aid, None)
            self.stations.submit(hoist, Shelve(u.name, "opcua", alarm=aid, minutes=ms / 60_000.0,
                                               reason=comment or "TimedShelve over OPC UA"))
            return ua.StatusCode()
        if shelved and aid in h.one_shot:
            return ua.StatusCode(ua.StatusCodes.BadConditionAlreadyShelved)
        view = h.views.get(aid)
        h.one_shot[aid] = [u.name, bool(view is not None and view.present), False]
        self.stations.submit(hoist, Shelve(u.name, "opcua", alarm=aid, minutes=MAX_SHELVE_MIN,
                                           reason=comment or "OneShotShelve over OPC UA: until it returns to normal"))
        return ua.StatusCode()


#: the shelving methods a client may call on a condition's ShelvingState (or on the condition):
#: the ShelvedStateMachineType's, then the same on AlarmConditionType's instance declaration
SHELVING_METHODS = {
    "timed": ("ShelvedStateMachineType_TimedShelve", "ShelvedStateMachineType_TimedShelve2",
              "AlarmConditionType_ShelvingState_TimedShelve", "AlarmConditionType_ShelvingState_TimedShelve2"),
    "oneshot": ("ShelvedStateMachineType_OneShotShelve", "ShelvedStateMachineType_OneShotShelve2",
                "AlarmConditionType_ShelvingState_OneShotShelve", "AlarmConditionType_ShelvingState_OneShotShelve2"),
    "unshelve": ("ShelvedStateMachineType_Unshelve", "ShelvedStateMachineType_Unshelve2",
                 "AlarmConditionType_ShelvingState_Unshelve", "AlarmConditionType_ShelvingState_Unshelve2"),
}
#: ShelvedStateMachineType's states (ShelvingState/CurrentState/Id)
SHELVING_STATE_IDS = {"Unshelved": 2930, "TimedShelved": 2932, "OneShotShelved": 2933}


def _arg(x: Any) -> Any:
    from asyncua import ua
    return x.Value if isinstance(x, ua.Variant) else x


def _certificate_check(trust: TrustList) -> Any:
    """asyncua's certificate validator at CreateSession: BadCertificateUntrusted for a client
    certificate not in the trust list."""
    async def check(cert: Any, app: Any) -> None:
        from asyncua import ua
        from asyncua.common.utils import ServiceError
        from cryptography.hazmat.primitives.serialization import Encoding
        why = trust.why_refused(cert.public_bytes(Encoding.DER))
        if why is not None:
            log.warning("OPC UA client %s refused: %s", getattr(app, "ApplicationUri", "?"), why)
            raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)
    return check


def _ranges(h: Any) -> list[tuple[float, float]]:
    """Per rope: 0 to the pressure transmitter's full scale times the cylinder area, in kN (from
    the hoist's first node.json); else 0 to twice the rated rope tension; else none."""
    from ropemon.station.physical import load_node_json
    areas = list(h.site.cylinder_area_m2)
    try:
        p = load_node_json(h.spec.configs[0])[0]
        return [(0.0, round(p.sensor_p_max_Pa * a / 1000.0, 1)) for a in areas]
    except (ValueError, OSError, IndexError, AttributeError):
        pass
    if h.site.rated_rope_tension_n:
        return [(0.0, 2.0 * h.site.rated_rope_tension_n / 1000.0)] * len(areas)
    return []


# -- certificate ---------------------------------------------------------------------


def ensure_certificate(folder: Path, host: str) -> tuple[Path, Path]:
    """The server's certificate (DER) and key (PEM, mode 0600) in `folder`, made self-signed on
    first start (RSA 2048, SHA-256, 5 years; the application URI urn:ropemon:station:HOSTNAME
    and the endpoint's host in its subject alternative names)."""
    from asyncua.crypto.cert_gen import (dump_private_key_as_pem, generate_private_key,
                                         generate_self_signed_app_certificate)
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding
    from cryptography.x509.oid import ExtendedKeyUsageOID

    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    cert, key = folder / CERT_FILE, folder / KEY_FILE
    if cert.is_file() and key.is_file():
        if key.stat().st_mode & 0o077:
            raise RuntimeError(f"{key}: readable by others (mode {key.stat().st_mode & 0o777:o}): chmod 600 it")
        return cert, key
    pk = generate_private_key()
    uri = f"urn:ropemon:station:{socket.gethostname()}"
    names: list[x509.GeneralName] = [x509.UniformResourceIdentifier(uri), x509.DNSName(socket.gethostname())]
    if host and host != socket.gethostname():
        try:
            import ipaddress
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    c = generate_self_signed_app_certificate(pk, "ropemon station", {"organizationName": "ropemon"}, names,
                                             extended=[ExtendedKeyUsageOID.SERVER_AUTH,
                                                       ExtendedKeyUsageOID.CLIENT_AUTH], days=CERT_DAYS)
    files.write_private(key, dump_private_key_as_pem(pk))
    cert.write_bytes(c.public_bytes(Encoding.DER))
    return cert, key


def certificate_uri(path: Path) -> str | None:
    """The application URI in a DER certificate's subject alternative names."""
    from cryptography import x509
    try:
        c = x509.load_der_x509_certificate(path.read_bytes())
        uris = c.extensions.get_extension_for_class(x509.SubjectAlternativeName).value.get_values_for_type(
            x509.UniformResourceIdentifier)
    except (ValueError, OSError, x509.ExtensionNotFound):
        return None
    return uris[0] if uris else None


# -- the face's entry point ------------------------------------------------------------


def start(stations: Any, table: Any) -> OpcuaFace:
    """Check the [opcua] table, add the listener to every hoist, start the server (faces.py)."""
    import importlib.util

    from ropemon.station.faces import FaceError
    if importlib.util.find_spec("asyncua") is None:
        raise FaceError("[opcua]: the opcua face needs its libraries: pip install 'ropemon[opcua]'")
    cfg = parse_table(table, stations.file.path.parent)
    users = None
    if cfg.users is not None:
        from ropemon.station.users import Users, UsersError
        try:
            users = Users(cfg.users)
        except (UsersError, OSError) as e:
            raise StationFileError(f"opcua.users: {e}") from None
    face = OpcuaFace(stations, cfg, users)
    try:
        face.start()
    except RuntimeError as e:
        raise FaceError(str(e)) from None
    stations.add_listeners(lambda h: OpcuaListener(face, h.id))
    return face
