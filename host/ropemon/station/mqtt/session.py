"""A Sparkplug B edge node session as a state machine: no network, no threads, no clock.

The face (`ropemon.station.mqtt`) tells it what happened (connecting, connected, a PUBACK,
a command, the primary host's STATE, a record taken, an outbox row to send, disconnected)
with the time in ms since the epoch, and publishes the `Message`s it returns, in order.

It keeps: bdSeq (one more per connection, carried in the will NDEATH and in NBIRTH), seq
(NBIRTH 0, then one more per DBIRTH, DDEATH and DDATA, 255 -> 0), which devices are born,
each device's newest values (for DBIRTH), the cursor (the newest outbox row published in
the session) and `live_from` (rows from this id on were queued after the session's births:
older ones go out with is_historical), and the DDATA in flight (paho's message id -> outbox
row id) until their PUBACK. A device's death or birth is a row among its data
({DEVICE: "death" | "birth"}): DDEATH or DBIRTH when that row's turn comes.
"""
from __future__ import annotations

import json
from typing import Any, NamedTuple, Protocol

from ropemon.station.mqtt import sparkplug as sp

DEVICE = "$device"     # a record {DEVICE: "death" | "birth"}: the hoist lost or heard again
Metrics = list[tuple[str, int, str | None]]   # (name, datatype, unit): sparkplug.hoist_metrics


class Message(NamedTuple):
    topic: str
    payload: bytes
    qos: int
    row: int | None = None     # a DDATA: the outbox row it carries (in flight until its PUBACK)


class Rows(Protocol):
    """What the births read of the rows still to send (the face's `outbox.Outbox`)."""

    next_id: int

    def last_id(self) -> int: ...

    def first_states(self, row_id: int) -> dict[str, str]: ...

    def devices_between(self, after: int, before: int) -> set[str]: ...


class Session:
    """One edge node's Sparkplug B state across its connections (module docstring)."""

    def __init__(self, group_id: str, edge_node_id: str, devices: dict[str, Metrics], *, qos: int = 1,
                 primary_host_id: str | None = None, bdseq: int = -1) -> None:
        self.group_id, self.edge_node_id, self.qos = group_id, edge_node_id, qos
        self.primary_host_id = primary_host_id
        self.devices = devices
        self.datatype = {d: {n: t for n, t, _ in m} for d, m in devices.items()}
        self.alias = sp.aliases(devices)
        self.bdseq = bdseq                 # this connection's (the last one's before a connection)
        self.seq = 0
        self.births = False                # this connection's NBIRTH is out
        self.sessions = 0                  # connections that reached their births
        self.alive = {d: True for d in devices}     # the hoist heard, as of the newest record taken
        self.born = {d: False for d in devices}     # DBIRTH sent in this session, no DDEATH since
        self.last: dict[str, dict[str, tuple[int, Any]]] = {d: {} for d in devices}   # for DBIRTH
        self.cursor = 0                    # the newest outbox row published in this session
        self.live_from = 1 << 62           # rows from this id on were queued after this session's births
        self.dead_after: list[str] = []    # born for their stored data, dead at the live rows: DDEATH once it is out
        self.inflight: dict[int, int] = {}   # message id -> outbox row id, awaiting the PUBACK
        self.host_online = False           # the primary host's newest STATE (primary_host_id)
        self.host_ts = -1                  # that STATE's timestamp: an older one is ignored

    def topic(self, kind: str, device: str | None = None) -> str:
        return sp.topic(self.group_id, kind, self.edge_node_id, device)

    # -- the connection -------------------------------------------------------------------

    def connecting(self, now_ms: int) -> Message:
        """A new connection: the next bdSeq; returns the will (NDEATH with that bdSeq)."""
        self.bdseq = (self.bdseq + 1) % 256
        return self.ndeath(now_ms)

    def ndeath(self, now_ms: int) -> Message:
        """This connection's NDEATH (QoS 1, no seq): the will, or sent before a clean disconnect."""
        death = sp.payload(None, now_ms)
        sp.add_metric(death, "bdSeq", sp.INT64, self.bdseq, death.timestamp)
        return Message(self.topic("NDEATH"), death.SerializeToString(), 1)

    def connected(self) -> None:
        """The broker accepted the connection: no births yet, the primary host's STATE to come."""
        self.host_online = False
        self.births = False
        self.seq = 0

    def disconnected(self) -> list[int]:
        """The connection is gone: returns the rows of the DDATA still in flight, dropped here;
        they stay in the outbox and go out again (historical) after the next births."""
        self.births = False
        rows = list(self.inflight.values())
        self.inflight.clear()
        return rows

    def may_be_born(self) -> bool:
        """Births now, or wait for the primary host's STATE online (store and forward meanwhile)."""
        return not self.primary_host_id or self.host_online

    # -- what comes from the broker -------------------------------------------------------

    def puback(self, mid: int) -> int | None:
        """A PUBACK (or a QoS 0 message written): the outbox row it acknowledges, if a DDATA's."""
        return self.inflight.pop(mid, None)

    def command(self, data: bytes) -> bool:
        """An NCMD's payload: True when it asks for a rebirth (Node Control/Rebirth true)."""
        try:
            p = sp.decode(data)
        except Exception:  # noqa: BLE001 - not a Sparkplug payload: ignored
            return False
        return any(m.name == "Node Control/Rebirth" and sp.metric_value(m) for m in p.metrics)

    def host_state(self, data: bytes) -> bool:
        """The primary host's STATE, {"online": bool, "timestamp": ms}: True when it says the host
        went offline. One older than the newest taken is ignored (a stale retained message);
        ValueError when it is not Sparkplug's STATE."""
        try:
            state = json.loads(data)
            online, ts = state["online"], state["timestamp"]
            if not isinstance(online, bool) or not isinstance(ts, int) or isinstance(ts, bool):
                raise ValueError("online must be a boolean and timestamp an integer")
        except (ValueError, KeyError, TypeError) as e:
            raise ValueError(str(e)) from e
        if ts < self.host_ts:
            return False
        self.host_ts = ts
        self.host_online = online
        return not online

    # -- the session's births ---------------------------------------------------------------

    def begin(self, now_ms: int, rows: Rows) -> list[Message]:
        """The session's births on this connection: every row queued from now on is live, the rows
        still in the outbox go out first, historical."""
        self.live_from = rows.last_id() + 1
        self.cursor = 0
        out = self._births(now_ms, rows)
        self.sessions += 1
        return out

    def rebirth(self, now_ms: int, rows: Rows) -> list[Message]:
        """Born again when a host asks (NCMD), within the session: the cursor, `live_from` and the
        DDATA in flight stay."""
        return self._births(now_ms, rows)

    def _births(self, now_ms: int, rows: Rows) -> list[Message]:
        """NBIRTH (seq 0, bdSeq) and the DBIRTH of each hoist heard where publishing stands (the
        rows after the cursor are still to send) or with stored data still to send, with every
        metric's name, alias, unit and newest value. Where publishing stands, a hoist is as its
        first live death or birth row still to send says it was before it (a death: heard), or as
        of now without one: its rows still to send then replay its deaths and births in order. A
        hoist born only for its stored data is declared dead (DDEATH) once that data is out."""
        self.seq = 0
        nb = sp.payload(0, now_ms)
        sp.add_metric(nb, "bdSeq", sp.INT64, self.bdseq, nb.timestamp)
        sp.add_metric(nb, "Node Control/Rebirth", sp.BOOLEAN, False, nb.timestamp)
        out = [Message(self.topic("NBIRTH"), nb.SerializeToString(), 0)]
        cursor, live_from = self.cursor, self.live_from
        start = max(cursor + 1, live_from)         # the first live row still to send
        first = rows.first_states(start) if start < rows.next_id else {}
        alive = {d: first[d] == "death" if d in first else self.alive[d] for d in self.devices}
        stored = (rows.devices_between(cursor, live_from)
                  if cursor + 1 < live_from and not all(alive.values()) else set())
        self.born = {d: False for d in self.devices}
        for device in self.devices:
            if alive[device] or device in stored:
                out.append(self._dbirth(device, now_ms))
        self.dead_after = [d for d in self.devices if self.born[d] and not alive[d]]
        self.births = True
        return out

    def _next_seq(self) -> int:
        self.seq = (self.seq + 1) % 256
        return self.seq

    def _dbirth(self, device: str, now_ms: int) -> Message:
        p = sp.payload(self._next_seq(), now_ms)
        last, alias = self.last[device], self.alias[device]
        for name, datatype, unit in self.devices[device]:
            ts, value = last.get(name, (p.timestamp, None))
            sp.add_metric(p, name, datatype, value, ts, unit=unit, alias=alias[name])
        self.born[device] = True
        return Message(self.topic("DBIRTH", device), p.SerializeToString(), 0)

    def _ddeath(self, device: str, now_ms: int) -> Message:
        self.born[device] = False
        return Message(self.topic("DDEATH", device), sp.payload(self._next_seq(), now_ms).SerializeToString(), 0)

    def _deaths(self, now_ms: int) -> list[Message]:
        out = [self._ddeath(d, now_ms) for d in self.dead_after if self.born[d]]
        self.dead_after = []
        return out

    # -- the records and the outbox rows ----------------------------------------------------

    def taken(self, device: str, ts: int, values: dict[str, Any]) -> None:
        """A record queued by a hoist's listener: its death or birth, or its newest values."""
        if DEVICE in values:
            if device in self.alive:
                self.alive[device] = values[DEVICE] == "birth"
            return
        last = self.last[device]
        for k, v in values.items():
            last[k] = (ts, v)

    def row(self, row_id: int, device: str, ts: int, values: dict[str, Any], now_ms: int) -> list[Message]:
        """The next outbox row after the cursor: its DDATA (QoS `qos`, historical when queued before
        the births), or for a live death or birth row DDEATH or DBIRTH (QoS 0, as the
        specification asks), preceded by the DDEATHs due at the first live row. A row of a dead
        hoist or of one no longer in the station file gives nothing (a dead hoist's alarm bits go
        out with its next DBIRTH, which carries the newest values). Then `published`."""
        out = []
        if row_id >= self.live_from and self.dead_after:
            out += self._deaths(now_ms)
        if DEVICE in values:
            what = values[DEVICE]
            if row_id >= self.live_from and device in self.devices:
                if what == "death" and self.born[device]:
                    out.append(self._ddeath(device, now_ms))
                elif what == "birth" and not self.born[device]:
                    out.append(self._dbirth(device, now_ms))
            return out
        types = self.datatype.get(device)
        if types is None or not self.born[device]:
            return out
        p = sp.payload(self._next_seq(), now_ms)
        alias = self.alias[device]
        for name, value in values.items():
            if name in types:
                sp.add_metric(p, None, types[name], value, ts, historical=row_id < self.live_from, alias=alias[name])
        out.append(Message(self.topic("DDATA", device), p.SerializeToString(), self.qos, row_id))
        return out

    def published(self, row_id: int, mid: int | None) -> None:
        """`row`'s messages are out: the cursor moves to it; `mid`, its DDATA's message id, is in
        flight until its PUBACK (None: no DDATA, the row is done)."""
        self.cursor = row_id
        if mid is not None:
            self.inflight[mid] = row_id

    def caught_up(self, next_id: int, now_ms: int) -> list[Message]:
        """No row after the cursor: the cursor to the newest row queued (`next_id` - 1); the DDEATHs
        of the hoists born only for their stored data, which is out."""
        self.cursor = max(self.cursor, next_id - 1)
        return self._deaths(now_ms) if self.dead_after else []
