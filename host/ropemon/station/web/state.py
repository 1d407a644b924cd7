"""The web face's picture of one hoist: kept on the station's thread, read and pushed to the web's.

`WebListener(hoist)` is one more listener of the hoist's station (`Station.add_listeners`):
every method of it runs on the station's thread. It keeps, under its own lock,

- the last frame of each cage node, with the figures the page shows (compensated and raw
  tension per rope in kN, deviation from the mean, each piston's position in its stroke,
  sum against rated, depth, speed, battery, oil temperature) and when it came (station clock);
- the alarm state (`AlarmState`: active, hidden, each rope's band, each node's standing
  status), the links' status, the recent alarm events;
- a ring buffer of the last `TREND_S` seconds of each rope's compensated tension.

Browsers follow it through server-sent events: a client `subscribe`s with a `Subscriber`
(an asyncio queue on the web's event loop) and gets, atomically, a full snapshot, then every
change as a delta ("frame", "alarms", "status", "hoist", "event"), pushed from the station's thread with
`loop.call_soon_threadsafe`. The queue is bounded: a client that does not keep up is dropped
(its stream ends; the browser reconnects and gets a new snapshot), so the station never waits
for a browser. Messages are JSON text, serialised once for all clients.
"""
from __future__ import annotations

import asyncio
import json
import math
import threading
from collections import deque
from typing import Any

from ropemon.station.alarms import ActiveAlarm, AlarmEvent
from ropemon.station.link import Received
from ropemon.station.views import (HELD_BACK_WHY, STALE_S, alarm_text, has_positions, link_figures, merge_figures,
                                   piston)
from ropemon.station.pipeline import AlarmState, Listener, StationStatus
from ropemon.station.protocol import DAN_TO_N, Frame, L

TREND_S = 600.0          # the live trend: the last 10 minutes at frame rate
TREND_MAX = 20 * 600     # points kept per node at most (20 frames/s for 10 minutes)
QUEUE_MAX = 600          # messages waiting for one client before it is dropped (about 40 s of frames)
STATUS_EVERY_S = 1.0     # the links' status and the overview's summary at most this often
EVENTS_KEPT = 200        # recent alarm events on the live page (the store keeps them all)

__all__ = ["WebListener", "Subscriber", "STALE_S", "TREND_S"]


def _r(x: float | None, nd: int = 2) -> float | None:
    """A finite float rounded for JSON, or None."""
    if x is None or not math.isfinite(x):
        return None
    return round(float(x), nd)


def dumps(obj: Any) -> str:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False, default=str)


class Subscriber:
    """One browser's stream: a bounded asyncio queue on the web's loop, fed from any thread.

    Items are (event name, JSON text); None ends the stream (dropped, or the station stopped).
    """

    def __init__(self, loop: asyncio.AbstractEventLoop | None = None, maxsize: int = QUEUE_MAX) -> None:
        self.loop = loop or asyncio.get_running_loop()
        self.queue: asyncio.Queue[tuple[str, str] | None] = asyncio.Queue(maxsize)
        self.dropped = False      # fell behind (or the station stopped): the stream ends
        self.closed = False

    def send(self, item: tuple[str, str] | None) -> None:
        """Hand `item` to the client's loop (any thread; never blocks)."""
        if self.closed:
            return
        try:
            self.loop.call_soon_threadsafe(self._put, item)
        except RuntimeError:      # the loop is closed: the client is gone
            self.closed = True

    def close(self) -> None:
        self.send(None)
        self.closed = True

    def _put(self, item: tuple[str, str] | None) -> None:
        if self.dropped:
            return
        if item is None:
            self._end()
            return
        try:
            self.queue.put_nowait(item)
        except asyncio.QueueFull:
            self.dropped = True
            self._end()

    def _end(self) -> None:
        while not self.queue.empty():
            self.queue.get_nowait()
        self.queue.put_nowait(None)


def frame_view(f: Frame, at_s: float, area_m2: list[float], rated_load_n: float | None,
               battery_low_v: float | None) -> dict:
    """What the page shows of one frame (ropes numbered from 1 in `rope`)."""
    ropes: list[dict] = []
    present = [r.mean_dan != L.TENSION_ABSENT for r in f.ropes]
    comp = [r.mean_dan * DAN_TO_N if ok else None for r, ok in zip(f.ropes, present)]
    used = [c for c in comp if c is not None]
    mean = sum(used) / len(used) if used else 0.0
    raw_sum: float | None = 0.0
    held = f.held_back
    for i, r in enumerate(f.ropes):
        raw_n = None
        if r.raw_kpa != L.RAW_KPA_ABSENT and i < len(area_m2):
            raw_n = r.raw_kpa * 1000.0 * area_m2[i]
        if raw_n is None or comp[i] is None:
            raw_sum = None
        elif raw_sum is not None:
            raw_sum += raw_n
        c = comp[i]
        pos_m, pos_fault, near = piston(f, i)
        mask = f.stroke_mask
        ropes.append({
            "rope": i + 1,
            "comp_kN": _r(c / 1000 if c is not None else None),
            "raw_kN": _r(raw_n / 1000 if raw_n is not None else None),
            "raw_kpa": None if r.raw_kpa == L.RAW_KPA_ABSENT else r.raw_kpa,
            "min_kN": _r(r.min_dan * DAN_TO_N / 1000) if c is not None else None,
            "max_kN": _r(r.max_dan * DAN_TO_N / 1000) if c is not None else None,
            "dev": _r((c - mean) / mean, 4) if c is not None and mean > 0 else None,
            "fault": c is None,
            "pos_mm": _r(pos_m * 1000 if pos_m is not None else None, 1),   # from mid-stroke, + pulled out
            "pos_fault": pos_fault,                  # the displacement channel failed
            "near_lo": bool(mask >> (L.STROKE_LOW_SHIFT + i) & 1),    # the node saw the piston within the
            "near_hi": bool(mask >> (L.STROKE_HIGH_SHIFT + i) & 1),   # margin of the retracted / extended end
            "held_back": i in held,                  # the node held its compensation back at rest
        })
    total = sum(used)
    missing = [i + 1 for i, ok in enumerate(present) if not ok]
    bat_v = f.battery_mv / 1000
    return {
        "node": f.node, "seq": f.seq, "t": at_s, "time_ms": f.time_ms,
        "depth_m": _r(f.depth_mm / 1000), "speed_m_s": _r(f.speed_mm_s / 1000),
        "battery_v": _r(bat_v), "battery_low": bool(battery_low_v is not None and bat_v < battery_low_v)
        or "battery_low" in f.status_flags,
        "oil_c": _r(f.oil_temp_c, 1),
        "flags": [n for n in f.status_flags if n not in ("temp_absent", "held_back")],
        "held_back": [i + 1 for i in held],
        "held_why": HELD_BACK_WHY if held else "",
        "ropes": ropes,
        "status_only": not f.ropes,
        "positions": has_positions(f),
        "sum_kN": _r(total / 1000) if f.ropes else None,
        "raw_sum_kN": _r(raw_sum / 1000) if raw_sum is not None and f.ropes else None,
        "partial": bool(missing),
        "missing": missing,
        "load_frac": _r(total / rated_load_n, 4) if rated_load_n and f.ropes and not missing else None,
    }


def alarm_view(a: ActiveAlarm, first_out: bool = False) -> dict:
    return {
        "id": a.id, "kind": a.kind, "node": a.node, "rope": None if a.rope is None else a.rope + 1,
        "state": a.state, "priority": a.priority, "present": a.present, "latched": a.latched,
        "warning": a.warning, "value": _r(a.value, 4), "threshold": _r(a.threshold, 4), "worst": _r(a.worst, 4),
        "band": _r(a.band, 4), "text": alarm_text(a), "message": a.message,
        "raised_s": a.raised_s, "cleared_s": a.cleared_s, "acked_s": a.acked_s, "acked_by": a.acked_by,
        "shelved_until": a.shelved_until, "note": a.note, "first_out": first_out,
    }


def hoist_view(st: Any) -> dict:
    """A node's standing status (`AlarmEngine.hoist_status`): shown as status, never as an alarm."""
    return {"text": getattr(st, "text", ""), "hidden_frac": _r(getattr(st, "hidden_frac", None), 4)}


def event_view(e: AlarmEvent) -> dict:
    """An event as the page lists it: value and threshold as the log has them (`AlarmEvent.columns`)."""
    value, threshold = e.columns()
    return {"time_s": e.time_s, "action": e.action, "alarm": e.alarm, "kind": e.kind, "node": e.node,
            "rope": None if e.rope is None else e.rope + 1, "value": _r(value, 4),
            "threshold": _r(threshold, 4), "worst": _r(e.worst, 4), "message": e.message,
            "operator": e.operator, "annunciated": e.annunciated}


class WebListener(Listener):
    """One hoist's picture for the web (module docstring). `hoist` is a `hoists.Hoist`."""

    name = "web"

    def __init__(self, hoist: Any, trend_s: float = TREND_S) -> None:
        self.hoist_id: str = hoist.id
        self.hoist_name: str = hoist.name
        figures = hoist.figures
        self.area_m2 = list(figures.cylinder_area_m2)
        self.rated_load_n: float | None = figures.rated_load_n
        self.battery_low_v: float | None = figures.battery_low_v
        config = getattr(hoist, "config", None)
        self.site = {
            "rated_load_kN": _r(figures.rated_load_n / 1000 if figures.rated_load_n else None),
            "rated_rope_kN": _r(figures.rated_rope_tension_n / 1000 if figures.rated_rope_tension_n else None),
            "imbalance_frac": figures.imbalance_frac,
            "battery_low_v": figures.battery_low_v,
            "shaft_m": getattr(config, "shaft_m", None),
            "stale_s": STALE_S,
            "ropes": len(figures.cylinder_area_m2) or None,
            # each cylinder's stroke (end stops at +-stroke/2 from mid-stroke) and the margin, mm
            "stroke_mm": [_r(x * 1000, 1) for x in figures.stroke_m] or None,
            "margin_mm": _r(figures.stroke_margin_m * 1000, 1) if figures.stroke_margin_m else None,
        }
        self.trend_s = trend_s
        self._lock = threading.RLock()
        self._subs: set[Subscriber] = set()
        self._summary_subs: set[Subscriber] = set()
        self.nodes: dict[int, dict] = {}
        self.trend: dict[int, deque[tuple[float, list[float | None]]]] = {}
        self.alarms: dict = {"time_s": None, "active": [], "hidden": [], "bands": {}}
        self.hoist: dict = {}                    # node -> its standing status (hoist_view)
        self._hoist_sent: tuple[float, str] | None = None
        self._alarms_text = ""
        self.status: dict = {}
        self.events: deque[dict] = deque(maxlen=EVENTS_KEPT)
        self.now: float | None = None
        self.stopped = False
        self._status_sent: float | None = None
        self.frames = 0

    # -- the station's messages (station thread) ---------------------------------------

    def on_frame(self, item: Received, now_s: float) -> None:
        f = item.frame
        view = frame_view(f, now_s, self.area_m2, self.rated_load_n, self.battery_low_v)
        point = (now_s, [r["comp_kN"] for r in view["ropes"]])
        with self._lock:
            self.frames += 1
            self.nodes[f.node] = view
            if f.ropes:
                tr = self.trend.get(f.node)
                if tr is None:
                    tr = self.trend[f.node] = deque(maxlen=TREND_MAX)
                tr.append(point)
                while tr and tr[0][0] < now_s - self.trend_s:
                    tr.popleft()
            self._broadcast("frame", dumps(view))

    def on_event(self, event: AlarmEvent) -> None:
        ev = event_view(event)
        with self._lock:
            self.events.append(ev)
            self._broadcast("event", dumps(ev))

    def on_alarms(self, state: AlarmState) -> None:
        unacked = [a for a in state.active if a.latched]
        first = min(unacked, key=lambda a: (a.raised_s or 0.0, a.id)).id if unacked else None
        bands = {str(n): [None if b is None else {"dev": _r(b.dev, 4), "band": _r(b.band, 4), "reach": _r(b.reach, 4),
                                             "d_min": _r(b.d_min, 4), "d_max": _r(b.d_max, 4)}
                          for b in bl] for n, bl in state.bands.items()}
        view = {"active": [alarm_view(a, a.id == first) for a in state.active],
                "hidden": [alarm_view(a) for a in state.hidden], "bands": bands}
        text = dumps(view)
        hoist = {str(n): hoist_view(st) for n, st in state.hoist.items()}
        hoist_text = dumps(hoist)
        with self._lock:
            self.now = state.time_s
            # the standing status follows the rope tension: a change of its figures at most once
            # a second, a node's status coming or going at once
            sent = self._hoist_sent
            if sent is None or hoist.keys() != self.hoist.keys() or (
                    hoist_text != sent[1] and (state.time_s - sent[0] >= STATUS_EVERY_S or state.time_s < sent[0])):
                self.hoist = hoist
                self._hoist_sent = (state.time_s, hoist_text)
                self._broadcast("hoist", hoist_text)
            if text == self._alarms_text:
                return
            self._alarms_text = text
            self.alarms = dict(view, time_s=state.time_s)
            self._broadcast("alarms", dumps(self.alarms))
            self._send_summary()

    def on_status(self, status: StationStatus) -> None:
        down = {n: r.last_error or "not open" for n, r in status.receivers.items() if not r.connected}
        errors = {n: (r.callback_errors, r.last_callback_error) for n, r in status.receivers.items()
                  if r.callback_errors}
        rows = link_figures(status.merge, {n: r.counts for n, r in status.receivers.items()}, down, errors)
        shares: dict[str, float | None] = {}
        for name in status.receivers:
            s = [st["receivers"][name]["share"] for st in status.merge.values()
                 if name in st["receivers"] and st["receivers"][name]["share"] is not None]
            shares[name] = _r(sum(s) / len(s), 4) if s else None
        view = {
            "now": status.time_s,
            "receivers": [{"name": name, "figures": fig, "connected": name not in down,
                           "share": shares.get(name), "error": down.get(name)} for name, fig in rows],
            "merge": merge_figures(status.merge), "authenticated": status.authenticated,
            "dropped": status.dropped,
            "refused": {str(n): list(v) for n, v in status.rewound.items()},
            "faults": dict(status.faults),
        }
        with self._lock:
            self.now = status.time_s
            self.status = view
            if self._status_sent is None or status.time_s - self._status_sent >= STATUS_EVERY_S \
                    or status.time_s < self._status_sent:
                self._status_sent = status.time_s
                self._broadcast("status", dumps(view))
                self._send_summary()

    def on_stop(self, status: StationStatus) -> None:
        with self._lock:
            self.stopped = True
            self._broadcast("stop", dumps({"now": status.time_s}))
            for sub in self._subs | self._summary_subs:
                sub.close()
            self._subs.clear()
            self._summary_subs.clear()

    # -- the web's side (any thread) ---------------------------------------------------

    def close_subscribers(self) -> None:
        """End every client's stream (the web face stops)."""
        with self._lock:
            for sub in self._subs | self._summary_subs:
                sub.close()
            self._subs.clear()
            self._summary_subs.clear()

    def snapshot(self, trend: bool = True) -> dict:
        """Everything the live page shows, as plain JSON-able data (a copy)."""
        with self._lock:
            return self._snapshot(self._copy(trend))

    def _copy(self, trend: bool) -> tuple:
        """What a snapshot needs, copied under the lock (the views it holds are replaced, never
        changed, on the station's thread): quick, so the station never waits long."""
        return (self.now, dict(self.nodes), dict(self.alarms, hoist=self.hoist), self.status,
                list(self.events)[-50:], self.stopped,
                {n: list(tr) for n, tr in self.trend.items()} if trend else None)

    def _snapshot(self, copied: tuple) -> dict:
        now, nodes, alarms, status, events, stopped, trend = copied
        out = {
            "hoist": self.hoist_id, "name": self.hoist_name, "site": dict(self.site), "now": now,
            "nodes": {str(n): v for n, v in sorted(nodes.items())},
            "alarms": alarms, "status": status, "events": events, "stopped": stopped,
        }
        if trend is not None:
            out["trend"] = {str(n): self._trend_columns(tr) for n, tr in sorted(trend.items())}
        return out

    def summary(self) -> dict:
        """One hoist on the overview page."""
        with self._lock:
            active = self.alarms.get("active", [])
            nodes = {str(n): {"t": v["t"], "sum_kN": v["sum_kN"], "depth_m": v["depth_m"],
                              "speed_m_s": v["speed_m_s"], "partial": v["partial"], "load_frac": v["load_frac"]}
                     for n, v in sorted(self.nodes.items())}
            return {"hoist": self.hoist_id, "name": self.hoist_name, "now": self.now, "nodes": nodes,
                    "rated_load_kN": self.site["rated_load_kN"], "stale_s": STALE_S,
                    "active": len(active), "unacked": sum(1 for a in active if a["latched"]),
                    "alarms": [a["text"] for a in active[:3]],
                    "worst": min((a["priority"] for a in active if not a["warning"]), default=None),
                    "warnings": sum(1 for a in active if a["warning"]), "stopped": self.stopped}

    def alarm_ids(self) -> set[str]:
        """The alarms the page lists now (active and hidden): what an operator may act on."""
        with self._lock:
            return {a["id"] for a in self.alarms.get("active", [])} | {a["id"] for a in self.alarms.get("hidden", [])}

    def refused_nodes(self) -> set[int]:
        with self._lock:
            return {int(n) for n in self.status.get("refused", {})}

    def subscribe(self, sub: Subscriber) -> str:
        """Register `sub` for deltas; returns the snapshot (JSON) they follow: copied under the
        lock with the registration (no delta lost or doubled), serialised after it."""
        with self._lock:
            copied = self._copy(True)
            if self.stopped:
                sub.close()
            else:
                self._subs.add(sub)
        return dumps(self._snapshot(copied))

    def subscribe_summary(self, sub: Subscriber) -> str:
        with self._lock:
            snap = dumps(self.summary())
            if not self.stopped:
                self._summary_subs.add(sub)
            return snap

    def unsubscribe(self, sub: Subscriber) -> None:
        with self._lock:
            self._subs.discard(sub)
            self._summary_subs.discard(sub)

    def subscribers(self) -> int:
        with self._lock:
            return len(self._subs)

    # -- internals (under the lock) ------------------------------------------------------

    def _trend_columns(self, tr: list | deque) -> dict:
        """Columns for the chart; frames more than STALE_S apart get a gap (None) between them."""
        n = max((len(v) for _, v in tr), default=0)
        pts: list[tuple[float, list]] = []
        for t, v in tr:
            if pts and t - pts[-1][0] > STALE_S:
                pts.append(((t + pts[-1][0]) / 2, []))
            pts.append((t, v))
        return {"t": [round(t, 2) for t, _ in pts],
                "ropes": [[v[i] if i < len(v) else None for _, v in pts] for i in range(n)]}

    def _broadcast(self, event: str, data: str) -> None:
        gone = []
        for sub in self._subs:
            if sub.dropped or sub.closed:
                gone.append(sub)
            else:
                sub.send((event, data))
        for sub in gone:
            self._subs.discard(sub)

    def _send_summary(self) -> None:
        if not self._summary_subs:
            return
        data = dumps(self.summary())
        for sub in list(self._summary_subs):
            if sub.dropped or sub.closed:
                self._summary_subs.discard(sub)
            else:
                sub.send(("summary", data))
