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

The table is checked into `config.MqttConfig` (`parse_table`); what Sparkplug B asks of an edge node (births,
deaths, seq, bdSeq, rebirth, the primary host's STATE, the DDATA in flight) is
`session.Session`, which does no I/O: this module feeds it events and publishes what it returns.

Threads: one `SparkplugValues` listener per hoist on the station's thread turns each frame
(and each change of the alarm bits) into a record and puts it on a queue, never waiting;
it also says when the station stops hearing the hoist (the device's death: no frame from
any of its nodes for silent_s, or every receiver of the hoist down) and when it hears it
again (a frame: the device's birth). The publisher thread (`MqttFace`) owns everything else:
the outbox (`outbox.Outbox`, SQLite in the data_dir, deaths and births in order among the
data), the session, and the paho-mqtt client (a new one per connection, its NDEATH will
carrying that connection's bdSeq; its network loop run by this thread, not a paho thread: a
publish is written to the socket at once, acknowledgements and commands are read every
POLL_S). Each record is committed to the outbox before it is published (the durability point)
and kept in memory too: records newer than what has been published go out from memory, older
ones (a backlog, a previous run's) are read back from the outbox. A row leaves the outbox when
the broker acknowledges it (QoS 1): acknowledged rows are deleted together, every
`DELETE_EVERY` acknowledgements or `DELETE_S`, and before the outbox is read again after a
reconnection. A row queued before the current session's births goes out with is_historical;
a rebirth asked by a host (NCMD) within the session does not move that line.
"""
from __future__ import annotations

import logging
import queue
import ssl
import threading
import time
from collections import deque
from itertools import islice
from typing import Any

import paho.mqtt.client as paho

from ropemon.station.faces import StationView
from ropemon.station.mqtt import sparkplug as sp
from ropemon.station.mqtt.outbox import Outbox
from ropemon.station.mqtt.session import DEVICE, Message, Session
from ropemon.station.mqtt.config import DEADBANDS, SPARKPLUG_ID, MqttConfig, parse_table
from ropemon.station.scadavalues import HoistValues, NodeValues

__all__ = ["DEADBANDS", "DEVICE", "SPARKPLUG_ID", "MqttConfig", "MqttFace", "SparkplugValues", "parse_table", "start"]

log = logging.getLogger(__name__)
MAX_INFLIGHT = 200     # DDATA published and not yet acknowledged
BATCH = 200            # outbox rows read at a time
FRESH_MAX = 5000       # records kept in memory to publish (older ones are read from the outbox)
DELETE_EVERY = 200     # acknowledged rows deleted from the outbox together, this many ...
DELETE_S = 0.1         # ... or after this long
RETRY_S = (0.5, 5.0)   # reconnect back-off, first and longest
STANDING_EVERY_S = 10.0   # a node's standing_status text (it follows the rope tension) sent at most this often
POLL_S = 0.005         # the connection's incoming packets (acknowledgements, commands) read this often at most


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
            if self.face.config.report == "exception":
                values = self._moved(values)
        if alarms != self._alarms or (self.face.config.report == "frame" and v is not None):
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
        band = self.face.config.deadband
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
    """The publisher thread (module docstring): the queue, the outbox and paho around a `Session`."""

    def __init__(self, view: StationView, config: MqttConfig) -> None:
        self.config = config
        self.queue: "queue.SimpleQueue[tuple[str, int, dict]]" = queue.SimpleQueue()
        self.devices = {h.id: sp.hoist_metrics(sorted(h.keys)) for h in view.hoists.values()}
        self.session = Session(config.group_id, config.edge_node_id, self.devices, qos=config.qos,
                               primary_host_id=config.primary_host_id)
        self.alias = self.session.alias
        data_dir = view.config.data_dir
        if data_dir is not None:
            data_dir.mkdir(parents=True, exist_ok=True)
        self.outbox_path = data_dir / "mqtt-outbox.db" if data_dir is not None else None
        self.error: str | None = None            # the outbox cannot be written
        self.connected = False
        self.sent = 0                            # DDATA acknowledged (or sent, QoS 0)
        self.last_error: str | None = None       # why the last connection failed or ended
        self._said: str | None = None            # the failure last logged (said once, not at each retry)
        self._host_offline = threading.Event()
        self._stop = threading.Event()
        self._client: paho.Client | None = None
        self._lost = threading.Event()
        self._acked: deque[int] = deque()        # message ids paho says are acknowledged (or written, QoS 0)
        self._fresh: deque[tuple[int, str, int, dict]] = deque()   # (row id, device, ts, values) just queued
        self._done: list[int] = []                 # rows acknowledged (or not to send), to delete
        self._done_since = 0.0
        self._polled = 0.0
        self._rebirth = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mqtt", daemon=True)
        self._ready = threading.Event()

    # the session's state, read (and set by a connection) as the face's
    @property
    def bdseq(self) -> int:
        return self.session.bdseq

    @bdseq.setter
    def bdseq(self, value: int) -> None:
        self.session.bdseq = value

    @property
    def births(self) -> bool:
        """This connection's NBIRTH is out."""
        return self.session.births

    @births.setter
    def births(self, value: bool) -> None:
        self.session.births = value

    @property
    def seq(self) -> int:
        return self.session.seq

    @seq.setter
    def seq(self, value: int) -> None:
        self.session.seq = value

    @property
    def sessions(self) -> int:
        """Connections that reached their births."""
        return self.session.sessions

    @property
    def _inflight(self) -> dict[int, int]:
        return self.session.inflight

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
        s = self.config
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
            self.outbox = Outbox(self.outbox_path, self.config.buffer_max_frames)
        except Exception as e:  # noqa: BLE001 - reported by start()
            self.error = f"cannot open the outbox {self.outbox_path}: {e}"
            self._ready.set()
            return
        self.session.bdseq = self.outbox.meta("bdseq", -1)
        self._ready.set()
        session = self.session
        retry_at, delay = 0.0, RETRY_S[0]
        try:
            while not self._stop.is_set():
                self._take(timeout=0.02)
                self._poll()
                if self._client is not None and self._host_offline.is_set():
                    self._host_offline.clear()     # the primary host went offline: NDEATH, disconnect, start over
                    if session.births:
                        log.warning("MQTT: the primary host %s is offline: NDEATH, reconnecting to wait for it",
                                    self.config.primary_host_id)
                        self._close(keep_outbox=True)
                        self._acked.clear()
                        retry_at = 0.0
                        continue
                if self._client is not None and self._lost.is_set():
                    self._drop_client()
                    self._take_acks()               # those that came: their rows are not sent again
                    self._flush(force=True)
                    session.disconnected()          # the others stay in the outbox, to send again
                    self._acked.clear()
                if self._client is None:
                    if time.monotonic() >= retry_at:
                        if self._connect():
                            delay = RETRY_S[0]
                        else:
                            retry_at = time.monotonic() + delay
                            delay = min(delay * 2, RETRY_S[1])
                    continue
                if not session.births:
                    if not session.may_be_born():
                        continue                   # store and forward: the outbox grows meanwhile
                    self._send(session.begin(sp.now_ms(), self.outbox))
                if self._rebirth.is_set():       # asked by a host (NCMD): the same session, born again;
                    self._rebirth.clear()        # what was queued in it since its births stays live
                    self._send(session.rebirth(sp.now_ms(), self.outbox))
                self._take_acks()
                self._flush()
                self._publish_rows()
        except Exception as e:  # noqa: BLE001 - the station alarms on it (health)
            log.exception("mqtt publisher failed")
            self.error = f"the publisher stopped: {type(e).__name__}: {e}"
        finally:
            self._take(timeout=0)
            self._close()

    def _publish_rows(self) -> None:
        """The next rows after the session's cursor, as many as MAX_INFLIGHT leaves room for; a
        row without a DDATA in flight is done at once."""
        session = self.session
        if len(session.inflight) >= MAX_INFLIGHT:
            return
        rows = self._rows_after(session.cursor, min(BATCH, MAX_INFLIGHT - len(session.inflight)))
        for row_id, device, ts, values in rows:
            mid: int | None = None
            for m in session.row(row_id, device, ts, values, sp.now_ms()):
                got = self._publish(m)
                if m.row is not None:
                    if got is None:
                        return                 # the connection is lost: the row is sent again later
                    mid = got
            session.published(row_id, mid)
            if mid is None:
                self._finished(row_id)
        if not rows:                   # nothing after the cursor: none to read until a newer row
            self._send(session.caught_up(self.outbox.next_id, sp.now_ms()))

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
            row = self.session.puback(self._acked.popleft())
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
        """Queued records into the session, the outbox, in one transaction (committed), and memory."""
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
            self.session.taken(device, ts, values)
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
        s = self.config
        will = self.session.connecting(sp.now_ms())
        self.outbox.set_meta("bdseq", self.session.bdseq)
        c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=s.client_id, clean_session=True,
                        protocol=paho.MQTTv311)
        c.will_set(will.topic, will.payload, qos=will.qos, retain=False)
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
        c.subscribe(self.session.topic("NCMD"), qos=1)
        self.session.connected()
        if s.primary_host_id:                  # the retained STATE arrives at once if the host is there
            c.subscribe(f"{sp.NAMESPACE}/STATE/{s.primary_host_id}", qos=1)
        self._client = c
        self.connected = True
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
        self.session.births = False
        sock = c.socket() if c is not None else None
        if sock is not None:         # closed, not DISCONNECTed: the broker sends the will
            sock.close()

    def _on_command(self, client, userdata, msg) -> None:
        """An NCMD (a rebirth, asked by a host) or the primary host's STATE."""
        if msg.topic.startswith(f"{sp.NAMESPACE}/STATE/"):
            try:
                offline = self.session.host_state(msg.payload)
            except ValueError as e:
                log.warning("MQTT: the primary host's STATE is not Sparkplug's "
                            '{"online": bool, "timestamp": ms} (%s): ignored', e)
                return
            if offline:
                self._host_offline.set()
            return
        if self.session.command(msg.payload):
            self._rebirth.set()

    def _publish(self, m: Message) -> int | None:
        """One of the session's messages, never retained: its message id (None: the connection is lost)."""
        assert self._client is not None
        info = self._client.publish(m.topic, m.payload, qos=m.qos, retain=False)
        if info.rc != paho.MQTT_ERR_SUCCESS:
            self._lost.set()
            return None
        return info.mid

    def _send(self, messages: list[Message]) -> None:
        for m in messages:
            self._publish(m)

    def _close(self, keep_outbox: bool = False) -> None:
        """NDEATH before a clean disconnect; what is not acknowledged stays in the outbox."""
        c = self._client
        if c is not None and not self._lost.is_set():
            death = self.session.ndeath(sp.now_ms())
            end = time.monotonic() + 3.0
            while self.session.inflight and time.monotonic() < end and not self._lost.is_set():
                self._take_acks()     # the DDATA in flight: acknowledged rows leave the outbox
                self._poll(0.01, force=True)
            self._take_acks()
            try:
                info = c.publish(death.topic, death.payload, qos=death.qos)
                end = time.monotonic() + 2.0
                while not info.is_published() and time.monotonic() < end and not self._lost.is_set():
                    self._poll(0.05, force=True)
            except (RuntimeError, ValueError):
                pass
            c.disconnect()
        self._client = None
        self.connected = False
        self.session.disconnected()
        if hasattr(self, "outbox"):
            self._flush(force=True)
            if not keep_outbox:
                self.outbox.close()


def start(view: StationView, config: MqttConfig) -> MqttFace:
    """Add one `SparkplugValues` per hoist, start the publisher (the faces contract, `ropemon.station.faces`)."""
    face = MqttFace(view, config)
    view.add_listeners(lambda h: SparkplugValues(face, h.id, sorted(h.keys), view.config.silent_s))
    face.start()
    return face
