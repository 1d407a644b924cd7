"""The OPC UA face's alarm conditions: the station's alarm state as AlarmConditionType events,
Acknowledge and the ShelvedStateMachine's methods as the station's commands (docs/integration.md),
the method's result the command's outcome (`_carry_out`).

`_Conditions` is a part of `OpcuaFace` (face.py): its methods run on the face, with the face's
attributes and its `_object`, `_nid` and `_write`.
"""
from __future__ import annotations

import contextvars
import datetime
import logging
import math
import time
import uuid
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

from ropemon.station.alarms import PRIORITY, ActiveAlarm
from ropemon.station.commands import Command, CommandOutcome, Ticket, outcome_within
from ropemon.station.opcua.history import _utc
from ropemon.station.pipeline import Acknowledge, AlarmState, Shelve, Unshelve
from ropemon.station.scadavalues import standing_of

if TYPE_CHECKING:
    from ropemon.station.faces import StationView
    from ropemon.station.opcua.face import _Hoist

log = logging.getLogger("ropemon.station.opcua")

#: OPC UA Severity (1..1000) of each station alarm priority (1 highest).
SEVERITY = {1: 800, 2: 500, 3: 300}
MAX_SHELVE_MIN = 720.0       # the longest TimedShelve, and a OneShotShelve's bound (as the web face's)

_CALLER: contextvars.ContextVar[Any] = contextvars.ContextVar("ropemon_opcua_caller", default=None)

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


class _Conditions:
    """The alarm conditions of `OpcuaFace` (which this class is a base of)."""

    station: StationView
    users: Any
    server: Any
    hoists: dict[str, _Hoist]
    by_condition: dict[Any, tuple[str, str]]
    by_shelving: dict[Any, tuple[str, str]]
    event_ids: dict[bytes, tuple[str, str]]
    # the face's own (face.py)
    _nid: Callable[[str], Any]
    _object: Callable[..., Awaitable[Any]]
    _write: Callable[..., Awaitable[None]]

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
                _log_refusal(h.id, self.station.submit(h.id, Unshelve(user, "opcua one-shot", alarm=aid)))

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
        return await self._carry_out(hoist, Acknowledge(u.name, "opcua", alarm=aid))

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
            return await self._carry_out(hoist, Unshelve(u.name, "opcua", alarm=aid))
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
            return await self._carry_out(hoist, Shelve(u.name, "opcua", alarm=aid, minutes=ms / 60_000.0,
                                                       reason=comment or "TimedShelve over OPC UA"))
        if shelved and aid in h.one_shot:
            return ua.StatusCode(ua.StatusCodes.BadConditionAlreadyShelved)
        view = h.views.get(aid)
        h.one_shot[aid] = [u.name, bool(view is not None and view.present), False]
        code = await self._carry_out(hoist, Shelve(u.name, "opcua", alarm=aid, minutes=MAX_SHELVE_MIN,
                                                   reason=comment or "OneShotShelve over OPC UA: until it returns "
                                                   "to normal"))
        if not code.is_good():
            h.one_shot.pop(aid, None)
        return code

    async def _carry_out(self, hoist: str, command: Command) -> Any:
        """Hand `command` to the hoist's station and wait for its outcome (`OUTCOME_WAIT_S` at
        most): Good when carried out, BadInvalidState when the station refused it (logged). Good
        too when the station has not answered in time: it carries the command out later, a
        refusal then only logged."""
        from asyncua import ua
        ticket = self.station.submit(hoist, command)
        out = await outcome_within(ticket)
        if out is None:
            _log_refusal(hoist, ticket)
            return ua.StatusCode()
        if not out.ok:
            _log_refused(hoist, out)
            return ua.StatusCode(ua.StatusCodes.BadInvalidState)
        return ua.StatusCode()


def _log_refused(hoist: str, out: CommandOutcome) -> None:
    who = out.command.operator if out.command is not None else "?"
    log.warning("hoist %s: %s %s by %s refused: %s", hoist, out.action, out.alarm, who, out.reason)


def _log_refusal(hoist: str, ticket: Ticket) -> None:
    """Log the face's own command if the station refuses it (whenever it carries it out)."""
    def done(t: Ticket) -> None:
        if not t.cancelled() and t.exception() is None and not t.result().ok:
            _log_refused(hoist, t.result())
    ticket.add_done_callback(done)
