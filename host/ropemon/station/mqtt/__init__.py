"""The MQTT face: the station as a Sparkplug B edge node, each hoist a device (docs/integration.md).

    [mqtt]
    host = "broker.mine.local"
    port = 1883                 # 8883 with TLS
    group_id = "mine"           # Sparkplug group id
    edge_node_id = "shaft-2"    # Sparkplug edge node id: this station
    client_id = "ropemon-shaft-2"
    report = "frame"            # "frame": every frame's metrics; "exception": those that moved
    deadband = { kN = 0.5 }     # report = "exception": change needed per unit (defaults below)
    qos = 1                     # DDATA's QoS (1: acknowledged, so store-and-forward loses nothing)
    keepalive_s = 10
    username = "ropemon"        # optional, with password_file (the password's only line)
    password_file = "mqtt-password"
    tls = false                 # true: TLS, the system's CAs or tls_ca; tls_cert/tls_key: client cert
    buffer_max_frames = 2000000
    primary_host_id = "scada"   # optional: births only while spBv1.0/STATE/scada says online

Threads: one `SparkplugValues` listener per hoist on the station's thread turns each frame
(and each change of the alarm bits) into a record and puts it on a queue, never waiting;
it also says when the station stops hearing the hoist (the device's death: no frame from
any of its nodes for silent_s, or every receiver of the hoist down) and when it hears it
again (a frame: the device's birth). The publisher thread owns everything else: the outbox
(`outbox.Outbox`, SQLite in the data_dir, deaths and births in order among the data), the
paho-mqtt client (a new one per connection, its NDEATH will carrying that connection's
bdSeq; its network loop run by this thread, not a paho thread: a publish is written to the
socket at once, acknowledgements and commands are read every POLL_S), the primary host's STATE, NBIRTH/DBIRTH/DDEATH, seq, and sending the outbox in
order. Each record is committed to the outbox before it is published (the durability point)
and kept in memory too: records newer than what has been published go out from memory, older
ones (a backlog, a previous run's) are read back from the outbox. A row leaves the outbox when
the broker acknowledges it (QoS 1): acknowledged rows are deleted together, every
`DELETE_EVERY` acknowledgements or `DELETE_S`, and before the outbox is read again after a
reconnection. A row queued before the current session's births goes out with is_historical;
a rebirth asked by a host (NCMD) within the session does not move that line.
"""
from __future__ import annotations

import json
import logging
import queue
import re
import ssl
import threading
import time
from collections import deque
from itertools import islice
from pathlib import Path
from typing import Any

import paho.mqtt.client as paho

from ropemon.station.tomlfields import Table
from ropemon.station.mqtt import sparkplug as sp
from ropemon.station.mqtt.outbox import Outbox
from ropemon.station.scadavalues import HoistValues, NodeValues
from ropemon.station.stationfile import StationFileError

log = logging.getLogger(__name__)
SPARKPLUG_ID = re.compile(r"^[^/+#]{1,64}$")
DEADBANDS = {"kN": 0.5, "%": 0.1, "m": 0.1, "mm": 0.5, "m/s": 0.05, "V": 0.05, "degC": 0.5}
DEVICE = "$device"     # a record {DEVICE: "death" | "birth"}: the hoist lost or heard again
MAX_INFLIGHT = 200     # DDATA published and not yet acknowledged
BATCH = 200            # outbox rows read at a time
FRESH_MAX = 5000       # records kept in memory to publish (older ones are read from the outbox)
DELETE_EVERY = 200     # acknowledged rows deleted from the outbox together, this many ...
DELETE_S = 0.1         # ... or after this long
RETRY_S = (0.5, 5.0)   # reconnect back-off, first and longest
STANDING_EVERY_S = 10.0   # a node's standing_status text (it follows the rope tension) sent at most this often
POLL_S = 0.005         # the connection's incoming packets (acknowledgements, commands) read this often at most


class Settings:
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
        if self.password_file is None:
            return None
        from ropemon.station import files
        return files.read_text(self.password_file, "MQTT password file", files.MAX_KEY_FILE,
                               StationFileError).strip()


def _path(base: Path, text: str) -> Path:
    p = Path(text)
    return p if p.is_absolute() else base / p


class SparkplugValues(HoistValues):
    """One hoist's records for the publisher (station thread; never waits)."""

    name = "mqtt"

    def __init__(self, face: "MqttFace", hoist: str, nodes: list[int], silent_s: float = 5.0) -> None:
        super().__init__(hoist, nodes)
        self.face = face
        self.units = {name: unit for name, _, unit in sp.hoist_metrics(self.nodes)}
        self.reported: dict[str, Any] = {}
        self._alarms: tuple | None = None
        self._standing: dict[int, str | None] = {n: None for n in self.nodes}   # the standing_status last queued
        self._standing_s: dict[int, float] = {}      # ... and when (the station clock)
        self.silent_s = silent_s
        self.alive = True                 # born with the session; dead while the station hears nothing
        self._heard_s: float | None = None   # the station clock at the newest frame (or the first tick)
        self._receivers: set[str] = set()
        self._all_down = False

    def on_status(self, status: Any) -> None:
        super().on_status(status)
        self._receivers = {n for n, r in status.receivers.items() if getattr(r, "url", None) is not None}
        if self._heard_s is None:
            self._heard_s = status.time_s

    def on_alarms(self, state: Any) -> None:
        super().on_alarms(state)          # the alarm bits of this tick first: the last word before a death
        down = {a.id for a in state.active + state.hidden if a.present and a.kind == "receiver_down"}
        all_down = bool(self._receivers) and all(f"receiver_down:{r}" in down for r in self._receivers)
        quiet = self._heard_s is not None and self.station_s - self._heard_s > self.silent_s
        if self.alive and (quiet or (all_down and not self._all_down)):
            self.alive = False
            self.face.queue.put((self.hoist, int(time.time() * 1000), {DEVICE: "death"}))
        self._all_down = all_down

    def changed(self, what: str, v: NodeValues | None) -> None:
        if v is not None:
            self._heard_s = v.station_s
            if not self.alive:            # heard again: born before this frame's data
                self.alive = True
                self.face.queue.put((self.hoist, int(v.wall_s * 1000), {DEVICE: "birth"}))
        alarms = (self.present_bits, self.unacked_bits, self.vouched, self.present_eq, self.unacked_eq)
        values: dict[str, Any] = {}
        if v is not None:
            values = sp.frame_values(v)
            hidden = self.standing[v.node].hidden_frac if v.node in self.standing else None
            values[f"node{v.node}/hidden_imbalance"] = None if hidden is None else round(hidden * 100, 3)
            if self.face.settings.report == "exception":
                values = self._moved(values)
        if alarms != self._alarms or (self.face.settings.report == "frame" and v is not None):
            self._alarms = alarms
            values.update({"alarms/present": alarms[0], "alarms/unacknowledged": alarms[1], "vouched": alarms[2],
                           "alarms/equalizer_present": alarms[3], "alarms/equalizer_unacknowledged": alarms[4]})
        for n, st in self.standing.items():       # the standing text: when it changes, at most every
            now = self.station_s                  # STANDING_EVERY_S (the newest then), and in DBIRTH
            if self._standing.get(n) != st.text and now - self._standing_s.get(n, -1e18) >= STANDING_EVERY_S:
                self._standing[n], self._standing_s[n] = st.text, now
                values[f"node{n}/standing_status"] = st.text
        if values:
            ts = int((v.wall_s if v is not None else time.time()) * 1000)
            self.face.queue.put((self.hoist, ts, values))

    def _moved(self, values: dict[str, Any]) -> dict[str, Any]:
        out = {}
        band = self.face.settings.deadband
        for name, x in values.items():
            if name.endswith("/frame_seq"):
                continue
            old = self.reported.get(name, ...)
            unit = self.units.get(name)
            if old is ... or x is None or old is None or unit is None:
                moved = old != x
            else:
                moved = abs(x - old) >= band[unit] if band[unit] > 0 else x != old
            if moved:
                out[name] = self.reported[name] = x
        if out:
            seq = next(k for k in values if k.endswith("/frame_seq"))
            out[seq] = values[seq]
        return out

    def health(self) -> str | None:
        return self.face.error


class MqttFace:
    """The publisher thread (module docstring)."""

    def __init__(self, stations: Any, settings: Settings) -> None:
        self.settings = settings
        self.queue: "queue.SimpleQueue[tuple[str, int, dict]]" = queue.SimpleQueue()
        self.devices = {h.id: sp.hoist_metrics(sorted(h.keys)) for h in stations.hoists.values()}
        self.datatype = {d: {n: t for n, t, _ in m} for d, m in self.devices.items()}
        self.alias = sp.aliases(self.devices)
        data_dir = stations.file.data_dir
        if data_dir is not None:
            data_dir.mkdir(parents=True, exist_ok=True)
        self.outbox_path = data_dir / "mqtt-outbox.db" if data_dir is not None else None
        self.error: str | None = None            # the outbox cannot be written
        self.connected = False
        self.bdseq = -1
        self.sessions = 0                        # connections that reached their births
        self.sent = 0                            # DDATA acknowledged (or sent, QoS 0)
        self.last_error: str | None = None       # why the last connection failed or ended
        self._said: str | None = None            # the failure last logged (said once, not at each retry)
        self.alive = {d: True for d in self.devices}    # the hoist heard, as of the newest record taken
        self.born = {d: False for d in self.devices}    # DBIRTH sent in this session, no DDEATH since
        self.host_online = False                 # the primary host's newest STATE (primary_host_id)
        self._host_ts = -1                       # that STATE's timestamp: an older one is ignored
        self._host_offline = threading.Event()
        self.births = False                      # this connection's NBIRTH is out
        self._stop = threading.Event()
        self._client: paho.Client | None = None
        self._lost = threading.Event()
        self._acked: deque[int] = deque()
        self._inflight: dict[int, int] = {}
        self._fresh: deque[tuple[int, str, int, dict]] = deque()   # (row id, device, ts, values) just queued
        self._done: list[int] = []                 # rows acknowledged (or not to send), to delete
        self._done_since = 0.0
        self._polled = 0.0
        self._rebirth = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mqtt", daemon=True)
        self._ready = threading.Event()

    # -- lifecycle ------------------------------------------------------------------------

    def start(self) -> None:
        self._thread.start()
        self._ready.wait(10.0)
        if self.error is not None:
            raise OSError(f"[mqtt]: {self.error}")

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(15.0)

    def describe(self) -> str:
        s = self.settings
        if self.connected and s.primary_host_id and not self.births:
            state = f"connected, waiting for the primary host {s.primary_host_id} to be online"
        else:
            state = "connected" if self.connected else f"not connected ({self.last_error or 'connecting'})"
        where = self.outbox_path or "memory"
        return (f"MQTT Sparkplug B to {s.host}:{s.port}{' (TLS)' if s.tls else ''}: group {s.group_id}, "
                f"edge node {s.edge_node_id}, {len(self.devices)} device(s), {s.report}; {state}; "
                f"store-and-forward in {where}")

    # -- the publisher thread ----------------------------------------------------------------

    def _run(self) -> None:
        try:
            self.outbox = Outbox(self.outbox_path, self.settings.buffer_max_frames)
        except Exception as e:  # noqa: BLE001 - reported by start()
            self.error = f"cannot open the outbox {self.outbox_path}: {e}"
            self._ready.set()
            return
        self.bdseq = self.outbox.meta("bdseq", -1)
        self._ready.set()
        self.last: dict[str, dict[str, tuple[int, Any]]] = {d: {} for d in self.devices}   # for DBIRTH
        retry_at, delay = 0.0, RETRY_S[0]
        cursor = 0                    # the newest outbox row published in this session
        live_from = 1 << 62           # rows from this id on were queued after this session's births
        self._dead_after: list[str] = []   # born for their stored data, dead at the live rows: DDEATH once it is out
        inflight = self._inflight      # mid -> outbox row id
        try:
            while not self._stop.is_set():
                self._take(timeout=0.02)
                self._poll()
                if self._client is not None and self._host_offline.is_set():
                    self._host_offline.clear()     # the primary host went offline: NDEATH, disconnect, start over
                    if self.births:
                        log.warning("MQTT: the primary host %s is offline: NDEATH, reconnecting to wait for it",
                                    self.settings.primary_host_id)
                        self._close(keep_outbox=True)
                        inflight.clear()
                        self._acked.clear()
                        retry_at = 0.0
                        continue
                if self._client is not None and self._lost.is_set():
                    self._drop_client()
                    self._take_acks()               # those that came: their rows are not sent again
                    self._flush(force=True)
                    inflight.clear()
                    self._acked.clear()
                if self._client is None:
                    if time.monotonic() >= retry_at:
                        if self._connect():
                            delay = RETRY_S[0]
                        else:
                            retry_at = time.monotonic() + delay
                            delay = min(delay * 2, RETRY_S[1])
                    continue
                if not self.births:
                    if self.settings.primary_host_id and not self.host_online:
                        continue                   # store and forward: the outbox grows meanwhile
                    live_from = self.outbox.last_id() + 1
                    cursor = 0
                    self._births(live_from)
                if self._rebirth.is_set():       # asked by a host (NCMD): the same session, born again;
                    self._rebirth.clear()        # what was queued in it since its births stays live
                    self._births(live_from, cursor, rebirth=True)
                self._take_acks()
                self._flush()
                if len(inflight) < MAX_INFLIGHT:
                    rows = self._rows_after(cursor, min(BATCH, MAX_INFLIGHT - len(inflight)))
                    for row_id, device, ts, values in rows:
                        if row_id >= live_from and self._dead_after:
                            self._deaths()
                        mid: int | None
                        if DEVICE in values:
                            mid = self._device_state(device, values[DEVICE]) if row_id >= live_from else 0
                        else:
                            mid = self._data(device, ts, values, historical=row_id < live_from)
                        if mid is None:
                            break
                        cursor = row_id
                        if mid == 0:
                            self._finished(row_id)
                        else:
                            inflight[mid] = row_id
                    if not rows:                   # nothing after the cursor: none to read until a newer row
                        cursor = max(cursor, self.outbox.next_id - 1)
                        if self._dead_after and self._client is not None:
                            self._deaths()
        except Exception as e:  # noqa: BLE001 - the station alarms on it (health)
            log.exception("mqtt publisher failed")
            self.error = f"the publisher stopped: {type(e).__name__}: {e}"
        finally:
            self._take(timeout=0)
            self._close()

    def _poll(self, timeout: float = 0.0, force: bool = False) -> None:
        """paho's network loop, run by this thread (no network thread: a publish writes to the
        socket at once): read what came (PUBACKs, NCMD, STATE), write what is left, keepalive."""
        c = self._client
        if c is None or self._lost.is_set():
            return
        now = time.monotonic()
        if not force and now - self._polled < POLL_S:
            return
        self._polled = now
        if c.loop(timeout=timeout) != paho.MQTT_ERR_SUCCESS:
            self._lost.set()

    def _rows_after(self, cursor: int, limit: int) -> list[tuple[int, str, int, dict[str, Any]]]:
        """The next rows to publish after `cursor`: from memory when the row after it is there
        (the fresh records follow each other by id up to the newest), else from the outbox."""
        fresh = self._fresh
        while fresh and fresh[0][0] <= cursor:
            fresh.popleft()
        if cursor >= self.outbox.next_id - 1:
            return []                          # nothing newer was queued
        if fresh and fresh[0][0] == cursor + 1:
            return list(islice(fresh, limit))
        return self.outbox.after(cursor, limit)

    def _take_acks(self) -> None:
        while self._acked:
            row = self._inflight.pop(self._acked.popleft(), None)
            if row is not None:
                self._finished(row)
                self.sent += 1

    def _finished(self, row_id: int) -> None:
        if not self._done:
            self._done_since = time.monotonic()
        self._done.append(row_id)

    def _flush(self, force: bool = False) -> None:
        """Delete the acknowledged rows in one transaction: every DELETE_EVERY, after DELETE_S,
        or now (`force`: before the outbox is read again, at a stop)."""
        if self._done and (force or len(self._done) >= DELETE_EVERY
                           or time.monotonic() - self._done_since >= DELETE_S):
            done, self._done = self._done, []
            self.outbox.delete(done)

    def _take(self, timeout: float) -> None:
        """Queued records into the outbox, in one transaction (committed), and into memory."""
        records = []
        try:
            records.append(self.queue.get(timeout=timeout) if timeout else self.queue.get_nowait())
            while True:
                records.append(self.queue.get_nowait())
        except queue.Empty:
            pass
        if not records:
            return
        for device, ts, values in records:
            if DEVICE in values:
                if device in self.alive:
                    self.alive[device] = values[DEVICE] == "birth"
                continue
            last = self.last[device]
            for k, v in values.items():
                last[k] = (ts, v)
        try:
            dropped = self.outbox.dropped
            first = self.outbox.add(records)
            self.error = None
        except Exception as e:  # noqa: BLE001 - disk full, I/O error: the station alarms on it
            self.error = f"cannot write the outbox {self.outbox_path}: {type(e).__name__}: {e}"
            return
        fresh = self._fresh                    # consecutive ids, up to the newest
        if self.outbox.dropped != dropped:     # past buffer_max_frames: the oldest rows are gone
            fresh.clear()
        fresh.extend((first + k, dev, ts, values) for k, (dev, ts, values) in enumerate(records))
        while len(fresh) > FRESH_MAX:
            fresh.popleft()

    # -- MQTT ---------------------------------------------------------------------------------

    def _connect(self) -> bool:
        s = self.settings
        self.bdseq = (self.bdseq + 1) % 256
        self.outbox.set_meta("bdseq", self.bdseq)
        c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=s.client_id, clean_session=True,
                        protocol=paho.MQTTv311)
        death = sp.payload(None)
        sp.add_metric(death, "bdSeq", sp.INT64, self.bdseq, death.timestamp)
        c.will_set(sp.topic(s.group_id, "NDEATH", s.edge_node_id), death.SerializeToString(), qos=1, retain=False)
        if s.username:
            c.username_pw_set(s.username, s.password())
        if s.tls:
            c.tls_set(ca_certs=str(s.tls_ca) if s.tls_ca else None,
                      certfile=str(s.tls_cert) if s.tls_cert else None,
                      keyfile=str(s.tls_key) if s.tls_key else None, tls_version=ssl.PROTOCOL_TLS_CLIENT)
        c.max_inflight_messages_set(MAX_INFLIGHT)
        up = threading.Event()
        result: list[Any] = []
        dropped: list[str] = []
        self._lost.clear()

        def on_connect(client, userdata, flags, reason, props):
            result.append(reason)
            up.set()

        def on_disconnect(client, userdata, flags, reason, props):
            if result and not result[0].is_failure:      # a refusal keeps its own reason
                self.last_error = f"disconnected: {reason}"
            else:
                dropped.append(f"the broker closed the connection: {reason}")
            self._lost.set()
            up.set()

        c.on_connect = on_connect
        c.on_disconnect = on_disconnect
        c.on_publish = lambda client, userdata, mid, reason, props: self._acked.append(mid)
        c.on_message = self._on_command
        try:
            c.connect(s.host, s.port, keepalive=s.keepalive_s)
        except (OSError, ValueError) as e:
            self._failed(f"cannot connect to {s.host}:{s.port}: {e}")
            return False
        end = time.monotonic() + 10.0           # paho's loop is run by this thread (`_poll`)
        while not up.is_set() and time.monotonic() < end:
            if c.loop(timeout=0.1) != paho.MQTT_ERR_SUCCESS and not up.is_set():
                dropped.append("the connection closed before the broker's CONNACK")
                break
        if not result or result[0].is_failure or self._lost.is_set():
            if result and result[0].is_failure:
                why = f"the broker refused the connection: {result[0]}"
                if s.username or "auth" in str(result[0]).lower() or "password" in str(result[0]).lower():
                    why += f" (user {s.username!r}: check mqtt.username and mqtt.password_file)"
            else:
                why = dropped[0] if dropped else "no CONNACK within 10 s"
            self._failed(why)
            c.disconnect()
            return False
        if self._said is not None:
            log.warning("MQTT: connected to %s:%s", s.host, s.port)
            self._said = None
        c.subscribe(sp.topic(s.group_id, "NCMD", s.edge_node_id), qos=1)
        self.host_online = False
        if s.primary_host_id:                  # the retained STATE arrives at once if the host is there
            c.subscribe(f"{sp.NAMESPACE}/STATE/{s.primary_host_id}", qos=1)
        self._client = c
        self.connected = True
        self.births = False
        self.seq = 0
        return True

    def _failed(self, why: str) -> None:
        """A connection that failed: not a station fault (the hoist does not depend on the
        broker); said once in the log and shown by describe()."""
        if why != self._said:
            log.warning("MQTT: %s", why)
            self._said = why
        self.last_error = why

    def _drop_client(self) -> None:
        c, self._client = self._client, None
        self.connected = False
        self.births = False
        sock = c.socket() if c is not None else None
        if sock is not None:         # closed, not DISCONNECTed: the broker sends the will
            sock.close()

    def _on_command(self, client, userdata, msg) -> None:
        if msg.topic.startswith(f"{sp.NAMESPACE}/STATE/"):
            self._on_state(msg.payload)
            return
        try:
            p = sp.decode(msg.payload)
        except Exception:  # noqa: BLE001 - not a Sparkplug payload: ignored
            return
        for m in p.metrics:
            if m.name == "Node Control/Rebirth" and sp.metric_value(m):
                self._rebirth.set()

    def _on_state(self, data: bytes) -> None:
        """The primary host's STATE: {"online": bool, "timestamp": ms}; one older than the newest
        taken is ignored (a stale retained message)."""
        try:
            state = json.loads(data)
            online, ts = state["online"], state["timestamp"]
            if not isinstance(online, bool) or not isinstance(ts, int) or isinstance(ts, bool):
                raise ValueError("online must be a boolean and timestamp an integer")
        except (ValueError, KeyError, TypeError) as e:
            log.warning("MQTT: the primary host's STATE is not Sparkplug's "
                        '{"online": bool, "timestamp": ms} (%s): ignored', e)
            return
        if ts < self._host_ts:
            return
        self._host_ts = ts
        self.host_online = online
        if not online:
            self._host_offline.set()

    def _publish(self, topic: str, p: Any, qos: int) -> int | None:
        assert self._client is not None
        info = self._client.publish(topic, p.SerializeToString(), qos=qos, retain=False)
        if info.rc != paho.MQTT_ERR_SUCCESS:
            self._lost.set()
            return None
        return info.mid

    def _next_seq(self) -> int:
        self.seq = (self.seq + 1) % 256
        return self.seq

    def _births(self, live_from: int, cursor: int = 0, rebirth: bool = False) -> None:
        """NBIRTH (seq 0, bdSeq) and the DBIRTH of each hoist heard where publishing stands (the
        rows after `cursor` are still to send) or with stored data still to send, with every
        metric's name, alias, unit and newest value. Where publishing stands, a hoist is as its
        first live death or birth row still to send says it was before it (a death: heard), or as
        of now without one: its rows still to send then replay its deaths and births in order. A
        hoist born only for its stored data is declared dead (DDEATH) once that data is out
        (`_deaths`). `rebirth`: asked by a host (NCMD) within the session, not a new session
        (`sessions` counts connections)."""
        s = self.settings
        self.seq = 0
        nb = sp.payload(0)
        sp.add_metric(nb, "bdSeq", sp.INT64, self.bdseq, nb.timestamp)
        sp.add_metric(nb, "Node Control/Rebirth", sp.BOOLEAN, False, nb.timestamp)
        self._publish(sp.topic(s.group_id, "NBIRTH", s.edge_node_id), nb, 0)
        start = max(cursor + 1, live_from)         # the first live row still to send
        first = self.outbox.first_states(start) if start < self.outbox.next_id else {}
        alive = {d: first[d] == "death" if d in first else self.alive[d] for d in self.devices}
        stored = (self.outbox.devices_between(cursor, live_from)
                  if cursor + 1 < live_from and not all(alive.values()) else set())
        self.born = {d: False for d in self.devices}
        for device in self.devices:
            if alive[device] or device in stored:
                self._dbirth(device)
        self._dead_after = [d for d in self.devices if self.born[d] and not alive[d]]
        self.births = True
        if not rebirth:
            self.sessions += 1

    def _dbirth(self, device: str) -> None:
        s = self.settings
        p = sp.payload(self._next_seq())
        last, alias = self.last[device], self.alias[device]
        for name, datatype, unit in self.devices[device]:
            ts, value = last.get(name, (p.timestamp, None))
            sp.add_metric(p, name, datatype, value, ts, unit=unit, alias=alias[name])
        self._publish(sp.topic(s.group_id, "DBIRTH", s.edge_node_id, device), p, 0)
        self.born[device] = True

    def _ddeath(self, device: str) -> None:
        s = self.settings
        self._publish(sp.topic(s.group_id, "DDEATH", s.edge_node_id, device), sp.payload(self._next_seq()), 0)
        self.born[device] = False

    def _deaths(self) -> None:
        for device in self._dead_after:
            if self.born[device]:
                self._ddeath(device)
        self._dead_after = []

    def _device_state(self, device: str, what: str) -> int:
        """A live death or birth row: DDEATH or DBIRTH (QoS 0, as the specification asks)."""
        if device not in self.devices:
            return 0
        if what == "death" and self.born[device]:
            self._ddeath(device)
        elif what == "birth" and not self.born[device]:
            self._dbirth(device)
        return 0

    def _data(self, device: str, ts: int, values: dict[str, Any], historical: bool) -> int | None:
        s = self.settings
        types = self.datatype.get(device)
        if types is None or not self.born[device]:
            # a hoist no longer in the station file, or dead: its rows are dropped (a dead hoist's
            # alarm bits go out with its next DBIRTH, which carries the newest values)
            return 0
        p = sp.payload(self._next_seq())
        alias = self.alias[device]
        for name, value in values.items():
            if name in types:
                sp.add_metric(p, None, types[name], value, ts, historical=historical, alias=alias[name])
        return self._publish(sp.topic(s.group_id, "DDATA", s.edge_node_id, device), p, s.qos)

    def _close(self, keep_outbox: bool = False) -> None:
        """NDEATH before a clean disconnect; what is not acknowledged stays in the outbox."""
        c = self._client
        if c is not None and not self._lost.is_set():
            s = self.settings
            death = sp.payload(None)
            sp.add_metric(death, "bdSeq", sp.INT64, self.bdseq, death.timestamp)
            end = time.monotonic() + 3.0
            while self._inflight and time.monotonic() < end and not self._lost.is_set():
                self._take_acks()     # the DDATA in flight: acknowledged rows leave the outbox
                self._poll(0.01, force=True)
            self._take_acks()
            try:
                info = c.publish(sp.topic(s.group_id, "NDEATH", s.edge_node_id), death.SerializeToString(), qos=1)
                end = time.monotonic() + 2.0
                while not info.is_published() and time.monotonic() < end and not self._lost.is_set():
                    self._poll(0.05, force=True)
            except (RuntimeError, ValueError):
                pass
            c.disconnect()
        self._client = None
        self.connected = False
        self.births = False
        if hasattr(self, "outbox"):
            self._flush(force=True)
            if not keep_outbox:
                self.outbox.close()


def start(stations: Any, table: dict) -> MqttFace:
    """Check the [mqtt] table, add one `SparkplugValues` per hoist, start the publisher."""
    settings = Settings(table, stations.file.path.parent, stations.file.name)
    face = MqttFace(stations, settings)
    stations.add_listeners(lambda h: SparkplugValues(face, h.id, sorted(h.keys), stations.file.silent_s))
    face.start()
    return face
