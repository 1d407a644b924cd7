"""The web face's reading of a hoist's log: trends over hours, the event and audit log, trips.

Each hoist's log is opened read-only (`Store(path, readonly=True)`) in a thread of its own
(`LogReader`: one worker, so the SQLite connection stays on the thread that made it) and read
there, never on the web's event loop nor the station's thread. The station's writer keeps
writing meanwhile (WAL): a reader sees what is committed. Every read is a `Store` method: no SQL here.
"""
from __future__ import annotations

import asyncio
import csv
import datetime
import io
import math
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ropemon.station.protocol import DAN_TO_N
from ropemon.station.report import MIN_TRAVEL_M, FrameTable, Rest, Trip, rest_of
from ropemon.station.store import Store, StoreError
from ropemon.station.store import StoredTrip

MAX_POINTS = 1500          # points per series of a history trend
REST_WINDOW_S = 120.0      # frames read before and after a trip for its rests
MAX_EVENTS = 2000          # rows of the event log per page at most
EVENT_ACTIONS = ("raise", "clear", "ack", "shelve", "unshelve", "out_of_service", "in_service", "accept",
                 "rebase", "refused", "error")


class LogReader:
    """One hoist's log, read in its own thread (module docstring)."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self._store: Store | None = None
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ropemon-web-log")

    def _get(self) -> Store:
        if self.path is None:
            raise StoreError("this hoist keeps no log (station.data_dir is not set)")
        if self._store is None:
            if not self.path.exists():
                raise StoreError(f"{self.path}: no log yet")
            self._store = Store(self.path, readonly=True)
        return self._store

    async def call(self, fn: Callable[..., Any], *args: Any) -> Any:
        """fn(store, *args) in the reader's thread."""
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._pool, lambda: fn(self._get(), *args))

    def close(self) -> None:
        def shut() -> None:
            if self._store is not None:
                self._store.close()
                self._store = None
        try:
            self._pool.submit(shut).result(timeout=5)
        except Exception:
            pass
        self._pool.shutdown(wait=False)


def _f(x: Any, nd: int = 2) -> float | None:
    if x is None:
        return None
    x = float(x)
    return round(x, nd) if math.isfinite(x) else None


# -- trends ------------------------------------------------------------------------------


def nodes(st: Store) -> list[int]:
    return st.nodes()


def history(st: Store, node: int, t0: float, t1: float, max_points: int = MAX_POINTS) -> dict:
    """Each rope's compensated tension of `node` between t0 and t1 (rx time), averaged into at
    most `max_points` buckets, with each bucket's lowest and highest window value and the depth."""
    span = max(t1 - t0, 1e-3)
    bucket = span / max_points
    rows = st.tension_buckets(node, t0, t1, bucket)
    frames = st.frame_buckets(node, t0, t1, bucket)
    # a bucket without frames between two with frames: a gap (None), so the chart does not bridge it
    gap_s = max(3 * bucket, 2.0)
    points: list[tuple[Any, ...]] = []
    for k, r in enumerate(frames):
        if k and r[1] - frames[k - 1][1] > gap_s:
            points.append((None, (r[1] + frames[k - 1][1]) / 2, None, 0))
        points.append(r)
    index: dict[Any, int] = {p[0]: k for k, p in enumerate(points) if p[0] is not None}
    n_ropes = max((r[1] for r in rows), default=-1) + 1
    mean: list[list[float | None]] = [[None] * len(points) for _ in range(n_ropes)]
    lo: list[list[float | None]] = [[None] * len(points) for _ in range(n_ropes)]
    hi: list[list[float | None]] = [[None] * len(points) for _ in range(n_ropes)]
    for b, rope, m, mn, mx in rows:
        at = index.get(b)
        if at is None:
            continue
        mean[rope][at] = _f(m * DAN_TO_N / 1000)
        lo[rope][at] = _f(mn * DAN_TO_N / 1000)
        hi[rope][at] = _f(mx * DAN_TO_N / 1000)
    return {"node": node, "t0": t0, "t1": t1, "bucket_s": bucket,
            "t": [_f(p[1], 3) for p in points],
            "depth_m": [None if p[2] is None else _f(p[2] / 1000) for p in points],
            "frames": sum(p[3] for p in points),
            "ropes": mean, "min": lo, "max": hi}


# -- the event and audit log ------------------------------------------------------------------


def events(st: Store, action: str | None = None, kind: str | None = None, node: int | None = None,
           text: str | None = None, t0: float | None = None, t1: float | None = None,
           operator_only: bool = False, limit: int = 500) -> list[dict]:
    """The events table, newest first, filtered (ropes numbered from 1)."""
    out = st.events(since=t0, until=t1, action=action, kind=kind, node=node, text=text,
                    operator_only=operator_only, newest_first=True, limit=min(max(limit, 1), MAX_EVENTS))
    for d in out:
        if d.get("rope") is not None:
            d["rope"] += 1
    return out


def event_kinds(st: Store) -> list[str]:
    return st.event_kinds()


# -- trips -----------------------------------------------------------------------------------


def _travel_m(st: Store, t: StoredTrip) -> float:
    return st.depth_span(t.node, t.first_frame_id, t.last_frame_id) / 1000


def trip_list(st: Store, limit: int = 200) -> list[dict]:
    """The store's trips, newest first, with how far each moved (creep at a landing: `wind` false)."""
    out = []
    for t in st.trips(newest_first=True, limit=limit):
        travel = _travel_m(st, t)
        out.append({"id": t.id, "node": t.node, "start_time": t.start_time, "end_time": t.end_time,
                    "start_depth_m": t.start_depth_mm / 1000,
                    "end_depth_m": None if t.end_depth_mm is None else t.end_depth_mm / 1000,
                    "travel_m": round(travel, 1), "wind": travel >= MIN_TRAVEL_M,
                    "duration_s": None if t.end_time is None else round(t.end_time - t.start_time, 1)})
    return out


def trip_detail(st: Store, trip_id: int, area_m2: list[float], shaft_m: float | None) -> dict | None:
    """One trip as `ropemon report` sees it: its frames from the rest before to the rest after
    (bounded by the neighbouring winds and REST_WINDOW_S), and the rests' figures. The node time
    is unwrapped over these frames (`FrameTable.from_frames`, `ropemon.station.nodetime`), so a
    wrap of the node's u32 time inside them moves neither a rest nor the chart's axis."""
    tr = st.trip(trip_id)
    if tr is None:
        return None
    same = st.trips(tr.node)
    k = next(i for i, t in enumerate(same) if t.id == tr.id)
    prev = next((t for t in reversed(same[:k]) if _travel_m(st, t) >= MIN_TRAVEL_M), None)
    nxt = next((t for t in same[k + 1:] if _travel_m(st, t) >= MIN_TRAVEL_M), None)
    lo_id = prev.last_frame_id if prev is not None and prev.last_frame_id is not None else -1
    hi_id = nxt.first_frame_id if nxt is not None else 1 << 62
    end_time = tr.end_time if tr.end_time is not None else tr.start_time
    stored = [sf for sf in st.frames(tr.node, tr.start_time - REST_WINDOW_S, end_time + REST_WINDOW_S)
              if lo_id <= sf.id < hi_id and sf.frame.ropes]
    if not stored:
        return {"trip": tr, "frames": None, "travel_m": _travel_m(st, tr), "report": None, "rx": []}
    n_ropes = len(stored[-1].frame.ropes)
    stored = [sf for sf in stored if len(sf.frame.ropes) == n_ropes]
    ids = np.array([sf.id for sf in stored])
    ft = FrameTable.from_frames([sf.frame for sf in stored], ordered=True)
    shaft = shaft_m or float(np.nanmax(ft.depth_m)) or 1.0
    end_id = tr.last_frame_id if tr.last_frame_id is not None else 1 << 62
    before, after = ids < tr.first_frame_id, ids >= end_id
    area = list(area_m2) or [float("nan")] * n_ropes
    start = rest_of(ft.take(before), area, shaft, "before") if before.any() else None
    end = rest_of(ft.take(after), area, shaft, "after") if after.any() else None
    report = Trip(tr.id, tr.node, ft, start, end)
    return {"trip": tr, "frames": ft, "travel_m": _travel_m(st, tr), "report": report,
            "rx": [sf.rx_time for sf in stored], "area": area}


def rest_rows(report: Trip) -> dict:
    """The paper's table (`report.trip_table`) as data: per rope raw and compensated kN at each rest."""
    rests: list[tuple[str, Rest]] = [(f"{r.where} ({when})", r) for when, r in (("left", report.start),
                                                                              ("arrived", report.end))
                                     if r is not None]
    n = report.frames.comp_n.shape[1]
    rows = [{"label": f"rope {i + 1}", "cells": [(_f(r.raw_n[i] / 1000, 1), _f(r.comp_n[i] / 1000, 1))
                                                  for _, r in rests]} for i in range(n)]
    rows.append({"label": "sum", "cells": [(_f(np.sum(r.raw_n) / 1000, 1), _f(np.sum(r.comp_n) / 1000, 1))
                                           for _, r in rests]})
    pistons = []
    if any(r.pos_m is not None for _, r in rests):   # each piston's rest position, mm from mid-stroke
        pistons = [{"label": f"rope {i + 1}",
                    "cells": [_f(r.pos_m[i] * 1000, 1) if r.pos_m is not None else None for _, r in rests]}
                   for i in range(n)]
    return {"columns": [c for c, _ in rests], "depths": [_f(r.depth_m, 1) for _, r in rests],
            "frames": [r.frames for _, r in rests], "rows": rows, "pistons": pistons}


def trip_series(detail: dict) -> dict:
    """The trip's frames for the page's chart: time from the first frame, each rope's
    compensated and raw tension in kN, depth."""
    ft: FrameTable = detail["frames"]
    t = ft.t_s - ft.t_s[0]
    raw = ft.raw_n(detail["area"])
    n = ft.comp_n.shape[1]

    def col(a: np.ndarray) -> list:
        return [_f(x / 1000) for x in a]

    return {"t": [_f(x, 2) for x in t], "depth_m": [_f(x) for x in ft.depth_m],
            "comp": [col(ft.comp_n[:, i]) for i in range(n)], "raw": [col(raw[:, i]) for i in range(n)],
            "t0_node_s": float(ft.t_s[0])}


def trip_csv(detail: dict) -> str:
    """The trip's frames as CSV (one row per frame, ropes numbered from 1)."""
    ft: FrameTable = detail["frames"]
    raw = ft.raw_n(detail["area"])
    n = ft.comp_n.shape[1]
    buf = io.StringIO()
    w = csv.writer(buf)
    pos = ft.has_positions
    w.writerow(["rx_time", "rx_time_utc", "node_time_s", "depth_m", "speed_m_s"]
               + [f"rope{i + 1}_comp_kN" for i in range(n)] + [f"rope{i + 1}_raw_kN" for i in range(n)]
               + ([f"rope{i + 1}_pos_mm" for i in range(n)] if pos else []))
    for k in range(len(ft)):
        rx = detail["rx"][k]
        utc = datetime.datetime.fromtimestamp(rx, datetime.timezone.utc).isoformat(timespec="milliseconds")
        vals = [ft.comp_n[k, i] / 1000 for i in range(n)] + [raw[k, i] / 1000 for i in range(n)]
        if pos:
            assert ft.pos_m is not None
            vals += [ft.pos_m[k, i] * 1000 for i in range(n)]
        w.writerow([f"{rx:.3f}", utc.replace("+00:00", "Z"), f"{ft.t_s[k]:.3f}", f"{ft.depth_m[k]:.3f}",
                    f"{ft.speed_m_s[k]:.3f}"] + ["" if not math.isfinite(v) else f"{v:.3f}" for v in vals])
    return buf.getvalue()


def trip_png(detail: dict) -> bytes:
    """`ropemon report`'s plot of the trip (needs matplotlib: the report extra)."""
    from ropemon.station.report import plot_trip
    with tempfile.TemporaryDirectory() as d:
        p = plot_trip(detail["report"], detail["area"], Path(d) / "trip.png")
        return p.read_bytes()
