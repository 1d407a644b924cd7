"""`ropemon report DB`: per-trip summary of rope tensions and PNG plots of each trip.

Like the paper's field-test table: for every wind, each rope's tension raw
(p_tap x A) and compensated at the pithead rest and at the shaft-bottom rest,
and their sum against the theoretical static load
(cage + payload + tail ropes hanging below the cage) x g. Where the frames carry
the pistons' positions: each piston's position at each rest, and across the
trips in the log the rope-adjustment forecast (`equalizer.adjust_forecast`): per
landing, each piston's rest-position trend per wind and the winds left before it
reaches the stroke margin.
"""
from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ropemon.station.nodetime import NodeClock
from ropemon.station.physical import G_M_S2
from ropemon.station.protocol import DAN_TO_N, L

REST_SPEED_M_S = 0.05   # slower than this: the cage is standing
SETTLE_S = 1.0          # skip the bounce right after the cage stops
MIN_REST_S = 2.0        # shorter standstills are not a rest at a landing
MIN_TRAVEL_M = 5.0      # a "trip" that moved the cage less is creep at a landing (loading), not a wind
REST_AVG_S = 5.0        # a rest's figure: the mean over this long after arrival / before departure


@dataclass
class FrameTable:
    """Merged frames of one node as arrays (one row per frame, time-ordered)."""

    t_s: np.ndarray          # node time, unwrapped (ropemon.station.nodetime): keeps counting through a wrap
    depth_m: np.ndarray
    speed_m_s: np.ndarray
    comp_n: np.ndarray       # (frames, ropes) compensated window-mean tension
    raw_kpa: np.ndarray      # (frames, ropes) tap pressure window mean
    status: np.ndarray
    pos_m: np.ndarray | None = None   # (frames, ropes) piston position from mid-stroke; NaN: none

    @classmethod
    def from_frames(cls, frames, ordered: bool = False) -> "FrameTable":
        """From `ropemon.station.protocol.Frame`s in the order they arrived; status-only frames
        (no ropes) are skipped, a rope whose sensor failed for the window is NaN. The node time
        is unwrapped in that order (`nodetime.NodeClock`: a wrap of the u32 `time_ms` inside
        the frames does not send the time back). Sorted by that time unless `ordered` (keep
        the caller's order)."""
        clock = NodeClock()
        timed = [(clock.ms(f), f) for f in frames]
        timed = [(ms, f) for ms, f in timed if f.ropes]
        if not ordered:
            timed.sort(key=lambda mf: mf[0])
        n = max((len(f.ropes) for _, f in timed), default=0)
        timed = [(ms, f) for ms, f in timed if len(f.ropes) == n]
        fs = [f for _, f in timed]
        return cls(
            t_s=np.array([ms / 1000 for ms, _ in timed], float),
            depth_m=np.array([f.depth_mm / 1000 for f in fs], float),
            speed_m_s=np.array([f.speed_mm_s / 1000 for f in fs], float),
            comp_n=np.array([[r.mean_dan * DAN_TO_N if r.mean_dan != L.TENSION_ABSENT else np.nan
                              for r in f.ropes] for f in fs], float).reshape(len(fs), n),
            raw_kpa=np.array([[r.raw_kpa if r.raw_kpa != L.RAW_KPA_ABSENT else np.nan
                               for r in f.ropes] for f in fs], float).reshape(len(fs), n),
            status=np.array([f.status for f in fs], int),
            pos_m=np.array([[np.nan if r.position_m is None else r.position_m for r in f.ropes]
                            for f in fs], float).reshape(len(fs), n),
        )

    def __len__(self) -> int:
        return len(self.t_s)

    def raw_n(self, area_m2: list[float]) -> np.ndarray:
        return self.raw_kpa * 1000.0 * np.asarray(area_m2, float)[None, : self.raw_kpa.shape[1]]

    def take(self, sel) -> "FrameTable":
        return FrameTable(self.t_s[sel], self.depth_m[sel], self.speed_m_s[sel], self.comp_n[sel],
                          self.raw_kpa[sel], self.status[sel], None if self.pos_m is None else self.pos_m[sel])

    @property
    def has_positions(self) -> bool:
        return self.pos_m is not None and bool(np.isfinite(self.pos_m).any())


@dataclass
class HoistLoad:
    """What the theoretical static load at the cage's rope ends depends on."""

    cage_kg: float
    tail_ropes: int
    tail_kg_per_m: float
    shaft_m: float

    def load_n(self, depth_m: float, payload_kg: float = 0.0) -> float:
        """Static sum of head-rope tensions at the cage: the tail ropes hang from
        the cage down to their loop at the shaft bottom."""
        tail_m = max(self.shaft_m - depth_m, 0.0)
        return (self.cage_kg + payload_kg + self.tail_ropes * self.tail_kg_per_m * tail_m) * G_M_S2

    @classmethod
    def from_site(cls, path: str | Path) -> "HoistLoad":
        from ropemon.commission.site import SiteError, in_file, load_site
        try:
            h = load_site(path).hoist
        except SiteError as e:  # named with the file: --config's node.json has fields of the same names
            raise in_file(e, path) from None
        return cls(h.cage_mass_kg, h.tail_ropes, h.tail_rope_kg_per_m, h.shaft_depth_m)


@dataclass
class Rest:
    """The cage standing at a landing next to a trip (REST_AVG_S after arriving,
    or before leaving)."""

    where: str               # "pithead" or "bottom"
    depth_m: float
    frames: int              # settled frames averaged
    raw_n: np.ndarray        # per rope, mean over the settled rest
    comp_n: np.ndarray
    t_s: float = 0.0         # node time in the middle of the averaged frames
    pos_m: np.ndarray | None = None   # per rope, the piston's mean position over the rest; NaN: none


@dataclass
class Trip:
    """One wind (the store's trip) with the rests before and after it."""

    number: int
    node: int
    frames: FrameTable       # from the rest before to the rest after
    start: Rest | None
    end: Rest | None

    @property
    def direction(self) -> str:
        a = self.start.where if self.start else "?"
        b = self.end.where if self.end else "?"
        return f"{a} -> {b}"

    def rest_at(self, where: str) -> Rest | None:
        for r in (self.start, self.end):
            if r is not None and r.where == where:
                return r
        return None


def rest_of(ft: FrameTable, area_m2: list[float], shaft_m: float, side: str) -> Rest | None:
    """The cage standing next to a trip, averaged over REST_AVG_S: just after it
    arrived and settled (`side="after"`), or just before it left (`"before"`), so
    that loading or unloading later in the rest does not blur the figure."""
    standing = np.flatnonzero(np.abs(ft.speed_m_s) < REST_SPEED_M_S)
    if standing.size == 0:
        return None
    t = ft.t_s[standing]
    if t[-1] - t[0] < MIN_REST_S:
        return None
    if side == "after":
        first = t[0] + SETTLE_S
        sel = standing[(t >= first) & (t < first + REST_AVG_S)]
    else:
        sel = standing[t > t[-1] - REST_AVG_S]
    if sel.size == 0:
        return None
    depth = float(np.median(ft.depth_m[sel]))
    with warnings.catch_warnings():   # a rope failed for the whole rest stays NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        return Rest("pithead" if depth < 0.5 * shaft_m else "bottom", depth, len(sel),
                    np.nanmean(ft.raw_n(area_m2)[sel], axis=0), np.nanmean(ft.comp_n[sel], axis=0),
                    float(np.median(ft.t_s[sel])),
                    np.nanmean(ft.pos_m[sel], axis=0) if ft.has_positions else None)


def _travel_m(ft: FrameTable, ids: np.ndarray, tr) -> float:
    """How far the cage moved during a stored trip."""
    end = tr.last_frame_id if tr.last_frame_id is not None else np.inf
    d = ft.depth_m[(ids >= tr.first_frame_id) & (ids <= end)]
    return float(d.max() - d.min()) if d.size else 0.0


def trips_from_store(store, area_m2: list[float], shaft_m: float | None = None) -> list[Trip]:
    """Every trip the store detected, with the rest before it (frames since the
    previous trip ended) and after it (frames until the next trip started)."""
    out: list[Trip] = []
    for node in sorted({t.node for t in store.trips()}):
        stored = [sf for sf in store.frames(node=node) if sf.frame.ropes]
        if not stored:
            continue
        n_ropes = len(stored[-1].frame.ropes)
        stored = [sf for sf in stored if len(sf.frame.ropes) == n_ropes]
        ids = np.array([sf.id for sf in stored])
        ft_all = FrameTable.from_frames([sf.frame for sf in stored], ordered=True)
        shaft = shaft_m or float(ft_all.depth_m.max()) or 1.0
        trips = [tr for tr in store.trips(node) if _travel_m(ft_all, ids, tr) >= MIN_TRAVEL_M]
        for k, tr in enumerate(trips):
            prev_end = trips[k - 1].last_frame_id if k > 0 else None
            lo = prev_end if prev_end is not None else -1
            hi = trips[k + 1].first_frame_id if k + 1 < len(trips) else np.inf
            end_id = tr.last_frame_id if tr.last_frame_id is not None else np.inf
            before = (ids >= lo) & (ids < tr.first_frame_id)
            after = (ids >= end_id) & (ids < hi)
            ft = ft_all.take((ids >= lo) & (ids < hi))
            if len(ft) == 0:
                continue
            out.append(Trip(len(out) + 1, node, ft,
                            rest_of(ft_all.take(before), area_m2, shaft, "before") if before.any() else None,
                            rest_of(ft_all.take(after), area_m2, shaft, "after") if after.any() else None))
    return out


def trip_table(trip: Trip, load: HoistLoad | None,
               payload_kg: dict[str, float] | Callable[[float], float] | None = None) -> str:
    """The paper's table for one trip, as text.

    `payload_kg` is the payload in the cage at each rest: by landing ("pithead",
    "bottom"), or a function of the rest's node time (when the log of loading is known).
    """
    payload_kg = payload_kg or {}

    def payload_in(r: Rest) -> float:
        return payload_kg(r.t_s) if callable(payload_kg) else payload_kg.get(r.where, 0.0)

    # Columns: the rest before and the rest after the wind, named by their landing.
    rests = [(f"{r.where} ({when})", r)
             for when, r in (("left", trip.start), ("arrived", trip.end)) if r is not None]
    cols = [c for c, _ in rests]
    t = trip.frames.t_s
    head = (f"trip {trip.number} (node {trip.node}): {trip.direction}, "
            f"node time {t[0]:.1f} .. {t[-1]:.1f} s, {len(t)} frames")
    lines = [head, f"{'':>12}" + "".join(f"{w:>22}" for w in cols),
             f"{'kN':>12}" + "".join(f"{'raw':>11}{'comp':>11}" for _ in cols)]
    if not cols:
        return head + "\n  no rest at a landing before or after this trip (log started or ended mid-wind)"
    ropes = trip.frames.comp_n.shape[1]
    for i in range(ropes):
        row = f"{'rope ' + str(i + 1):>12}"
        for w, r in rests:
            row += f"{r.raw_n[i] / 1000:11.1f}{r.comp_n[i] / 1000:11.1f}"
        lines.append(row)
    row = f"{'sum':>12}"
    for w, r in rests:
        row += f"{r.raw_n.sum() / 1000:11.1f}{r.comp_n.sum() / 1000:11.1f}"
    lines.append(row)
    if load is not None:
        row, err = f"{'theoretical':>12}", f"{'error %':>12}"
        for w, r in rests:
            th = load.load_n(r.depth_m, payload_in(r))
            row += f"{th / 1000:22.1f}"
            err += f"{(r.raw_n.sum() - th) / th * 100:+11.1f}{(r.comp_n.sum() - th) / th * 100:+11.1f}"
        lines += [row, err]
        if not payload_kg:
            lines.append(f"{'':>12}  (empty cage assumed: give --payload-kg when it was loaded)")
    if any(r.pos_m is not None for _, r in rests):
        lines.append(f"{'piston mm':>12}" + "".join(f"{w:>22}" for w in cols))
        for i in range(ropes):
            row = f"{'rope ' + str(i + 1):>12}"
            for _, r in rests:
                x = r.pos_m[i] if r.pos_m is not None else np.nan
                row += f"{x * 1000:+22.1f}" if np.isfinite(x) else f"{'--':>22}"
            lines.append(row)
    return "\n".join(lines)


def rest_positions(trips: list[Trip], where: str) -> list[list[float | None]]:
    """One entry per trip (a wind), oldest first: each piston's position at the rest the trip
    arrived at if that is `where`, else None for every rope (the winds between two arrivals at
    that landing still count as winds)."""
    out: list[list[float | None]] = []
    for t in trips:
        r = t.end
        n = t.frames.comp_n.shape[1]
        if r is None or r.where != where or r.pos_m is None:
            out.append([None] * n)
        else:
            out.append([float(x) if np.isfinite(x) else None for x in r.pos_m])
    return out


def adjust_table(trips: list[Trip], stroke_m: list[float] | None, margin_m: float | None) -> str:
    """The rope-adjustment forecast across the log's trips, per node and landing (the loads at
    one landing compare): each piston's rest-position trend per wind, where it stands, and the
    winds left before it reaches the margin of the end it heads for. "" without positions."""
    from ropemon.station.equalizer import adjust_forecast

    lines: list[str] = []
    for node in sorted({t.node for t in trips}):
        mine = [t for t in trips if t.node == node]
        if not any(t.end is not None and t.end.pos_m is not None for t in mine):
            continue
        head = f"rope adjustment (node {node}): the pistons' rest positions across {len(mine)} trips"
        if not stroke_m:
            lines += [head, "  give --config node.json (its physical.stroke_m) for the winds left before a margin"]
            continue
        margin_txt = f", margin {margin_m * 1000:.0f} mm" if margin_m else ""
        strokes = sorted({round(s * 1000, 1) for s in stroke_m})
        lines.append(head + f" (stroke {', '.join(f'{s:g}' for s in strokes)} mm{margin_txt})")
        for where in ("pithead", "bottom"):
            rests = rest_positions(mine, where)
            if not any(x is not None for w in rests for x in w):
                continue
            fc = adjust_forecast(rests, stroke_m, margin_m)
            for i, f in enumerate(fc):
                label = f"  at the {where}: rope {i + 1}" if i == 0 else f"{'':>{len(where) + 11}}rope {i + 1}"
                if f is None:
                    seen = any(i < len(w) and w[i] is not None for w in rests)
                    lines.append(f"{label}: {'too few rests for a trend' if seen else 'no position at its rests'}")
                    continue
                left = ("no end in sight" if f.winds_left is None else
                        f"within the {f.end} end's margin now: adjust the rope" if f.winds_left <= 0 else
                        f"{f.winds_left:.0f} winds left before the {f.end} end's margin")
                lines.append(f"{label}: {f.trend_m * 1000:+.2f} mm/wind, at {f.last_m * 1000:+.1f} mm, {left}")
    return "\n".join(lines)


def plot_trip(trip: Trip, area_m2: list[float], out: Path) -> Path:
    """PNG of each rope's raw and compensated tension over the trip, and the depth."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ft = trip.frames
    t = ft.t_s - ft.t_s[0]
    raw = ft.raw_n(area_m2)
    fig, (ax, axd) = plt.subplots(2, 1, figsize=(9, 6), sharex=True, height_ratios=(3, 1))
    for i in range(ft.comp_n.shape[1]):
        line, = ax.plot(t, ft.comp_n[:, i] / 1000, lw=1.0, label=f"rope {i + 1} compensated")
        ax.plot(t, raw[:, i] / 1000, lw=0.8, ls="--", color=line.get_color(), label=f"rope {i + 1} raw")
    ax.set_ylabel("tension, kN")
    ax.set_title(f"trip {trip.number}: {trip.direction}")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, ncol=4, loc="lower center")
    axd.plot(t, ft.depth_m, color="k", lw=1.0)
    axd.invert_yaxis()
    axd.set_ylabel("depth, m")
    axd.set_xlabel(f"time from node t = {ft.t_s[0]:.1f} s, s")
    axd.grid(True, alpha=0.3)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


# -- the command -------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("db", help="ropemon SQLite log (ropemon monitor --db, ropemon demo)")
    p.add_argument("--out", default=None, help="directory for the PNG plots and report.txt (default: beside DB)")
    p.add_argument("--config", help="node.json: cylinder areas for the raw tension p x A, and the stroke")
    p.add_argument("--area-m2", type=float, help="rod-less piston area of every cylinder, instead of --config")
    p.add_argument("--site", help="SITE.toml: cage mass, tail ropes and shaft depth for the theoretical load")
    p.add_argument("--payload-kg", type=float, nargs=2, metavar=("AT_PITHEAD", "AT_BOTTOM"),
                   help="payload in the cage at the pithead and at the bottom rest (default empty)")


def stroke_from(args: argparse.Namespace) -> tuple[list[float] | None, float | None]:
    """Each cylinder's stroke and the stroke margin (m): from --config, else --site, else unknown."""
    if args.config:
        from ropemon.station.nodefigures import NodeFigures
        f = NodeFigures.from_node_json(args.config)
        return (list(f.stroke_m) or None), f.stroke_margin_m
    if args.site:
        from ropemon.commission.site import SiteError, in_file, load_site
        try:
            cyl = load_site(args.site).cylinders
        except SiteError as e:
            raise in_file(e, args.site) from None
        return [c.stroke_m for c in cyl], cyl[0].stroke_margin_m if cyl else None
    return None, None


def areas_from(args: argparse.Namespace) -> list[float]:
    if args.config:
        from ropemon.station.nodefigures import NodeFigures
        return NodeFigures.from_node_json(args.config).cylinder_area_m2
    if args.area_m2:
        return [args.area_m2] * 4
    raise ValueError("the raw tension needs the piston area: give --config node.json or --area-m2")


def write_report(store, out_dir: Path, area_m2: list[float], load: HoistLoad | None,
                 payload_kg: dict[str, float] | Callable[[float], float] | None = None,
                 shaft_m: float | None = None, stroke_m: list[float] | None = None,
                 margin_m: float | None = None) -> tuple[str, list[Path]]:
    """The text report and one PNG per trip, then the rope-adjustment forecast where the frames
    carry positions (`stroke_m` per rope and `margin_m` for the winds left); returns (text,
    files written)."""
    trips = trips_from_store(store, area_m2, shaft_m if shaft_m else (load.shaft_m if load else None))
    if not trips:
        return "no trips in this log (the cage never moved, or the log is empty)", []
    out_dir.mkdir(parents=True, exist_ok=True)
    parts, files = [], []
    for trip in trips:
        parts.append(trip_table(trip, load, payload_kg))
        png = plot_trip(trip, area_m2, out_dir / f"trip{trip.number:03d}-node{trip.node}.png")
        parts.append(f"  plot: {png}")
        files.append(png)
    forecast = adjust_table(trips, stroke_m, margin_m)
    if forecast:
        parts.append(forecast)
    text = "\n\n".join(parts)
    (out_dir / "report.txt").write_text(text + "\n")
    files.append(out_dir / "report.txt")
    return text, files


def run(args: argparse.Namespace) -> int:
    from ropemon.station import files
    from ropemon.station.store import Store, StoreError

    db = Path(args.db)
    if not db.exists():
        print(f"ropemon report: {db}: no such file", file=sys.stderr)
        return 2
    try:  # a regular file that is an SQLite database (ropemon.station.files)
        files.check_sqlite(db)
    except files.FileRefused as e:
        print(f"ropemon report: {e}", file=sys.stderr)
        return 2
    try:
        area = areas_from(args)
        load = HoistLoad.from_site(args.site) if args.site else None
        stroke, margin = stroke_from(args)
    except (ValueError, OSError) as e:
        print(f"ropemon report: {e}", file=sys.stderr)
        return 2
    payload = dict(zip(("pithead", "bottom"), args.payload_kg)) if args.payload_kg else None
    try:
        store = Store(db, readonly=True)
    except StoreError as e:
        print(f"ropemon report: {e}", file=sys.stderr)
        return 2
    try:
        out = Path(args.out) if args.out else db.with_suffix("").parent / (db.stem + "-report")
        text, _files = write_report(store, out, area, load, payload, stroke_m=stroke, margin_m=margin)
    finally:
        store.close()
    print(text)
    return 0
