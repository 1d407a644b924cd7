"""The tension equalizer's health from the node's frames: pure trackers the alarm engine runs.

The cylinders' rod-less cavities share one oil manifold, so a load change (the loading, an
acceleration, the unloading: the ropes' pressures move together) moves every piston: its
oil compresses by `k dp` (`k`: the hydraulic compliance, m/Pa per rope) and the oil that
flows between the cylinders equalises the ropes. What the frames of layout version 3 show
of that (each rope's piston position `pos_01mm`, the node's `stroke_mask`):

- `stroke_check`: a piston within the stroke margin of an end (the node's mask, set at any
  sample of the window, or the window mean within the margin). There the equalizer no
  longer equalizes that rope: its tension is no longer `p A` +- the seal's friction.
- `EqualizingTracker`: a rope whose piston does not share the others' motion over a load
  change (a closed stop valve, a blocked hose, a seized seal), told apart by its pressure:
  departing from the others' (its tap reads a cylinder cut off from the manifold), or
  following them while its piston stays (a seized seal when it does not move at all). Only
  the departing pressure raises by default: a healthy seal at rest holds its piston through a
  load change as a seized one does (`EqualizerSettings.position_lag`).
- `OilTracker`: the trapped oil volume `sum A_i x_i`, less the compression `sum A_i k_i p_i`
  and the thermal expansion, drifting: oil lost, with the rate.
- `RestTracker` and `adjust_forecast`: each piston's position at the rests between winds,
  its trend from wind to wind (ropes creeping or slipping unequally on the Koepe wheel)
  and the winds left before it reaches its margin.

Every tracker keeps O(ropes) state (the rest log and the oil window a fixed number of
entries) and does constant work per frame; time is the caller's `now_s`, so a sequence of
frames replays the same. A rope whose displacement channel faulted in the window
(fault_mask bit 4+i) or that has no position is never judged here: SENSOR FAULT names it.
Units: positions in m from mid-stroke, x > 0 the piston pulled out by its rope (docs/model.md).
"""
from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple, Sequence

from ropemon.station.protocol import Frame, L

SEQ_BOOT_SHIFT = 20   # seq = (boot << 20) | count (docs/protocol.md)
POS_ABSENT = getattr(L, "POS_ABSENT", -32768)
STROKE_LOW_SHIFT = getattr(L, "STROKE_LOW_SHIFT", 0)
STROKE_HIGH_SHIFT = getattr(L, "STROKE_HIGH_SHIFT", 4)
DISPLACEMENT_SHIFT = L.FAULT_DISPLACEMENT_SHIFT
#: Thermal expansion of a mineral hydraulic oil (ISO VG46: 6.5-7.5e-4 per K).
OIL_EXPANSION_PER_K = 7e-4


@dataclass(frozen=True)
class EqualizerSettings:
    """The equalizer alarms' figures and thresholds (docs/operator.md, "The equalizer").

    Figures from the node config (`ropemon.station.nodefigures.alarm_settings`): empty or None where
    unknown, and then what needs them is not judged (a stroke alarm from the node's mask alone,
    no oil balance without the areas)."""

    areas_m2: tuple[float, ...] = ()             # per rope
    stroke_m: tuple[float, ...] = ()             # per rope; end stops at +-stroke/2 from mid-stroke
    margin_m: float | None = None                # the margin band within this of an end
    compliance_m_per_pa: tuple[float, ...] = ()  # k per rope (x moves k dp with pressure)
    # stroke_limit: raised on the first frame in the margin; cleared once the piston is this much
    # further from the end than the margin (and the node's mask is clear) for stroke_clear_s
    stroke_hysteresis_m: float = 0.002
    stroke_clear_s: float = 2.0
    # not_equalizing: over a load change this rope's piston moved less than the others' (their
    # median) by more than the tolerance (`motion_tolerance_m`: two steps of the frame's position
    # resolution plus move_sigmas x the rms noise of a difference of two frame means), and at most
    # lag_ratio of their motion (any share when its pressure departs from theirs); seized_ratio: not
    # at all. Clears when it moved with them (within 3/4 of the tolerance, follow_ratio of theirs)
    displacement_noise_m: float = 2e-5           # rms per sample (physical.displacement_noise_m)
    samples_per_frame: int = 20                  # sample_hz / frame_hz
    position_step_m: float = 1e-4                # the frame's resolution (pos_01mm: 0.1 mm)
    move_sigmas: float = 10.0
    move_min_m: float = 5e-5
    lag_ratio: float = 0.5
    lag_growth: float = 2.0                      # the lag held while the others' motion grew this much
    seized_ratio: float = 0.1
    follow_ratio: float = 0.8
    departure_kpa: float = 30.0                  # pressure departing from the others' by more than
    departure_frac: float = 0.05                 # max(this kPa, this share of their change)
    reanchor_m: float = 1e-3                     # the others moved this far: a new reference
    anchor_max_s: float = 300.0                  # or after this long (a lagging rope judged afresh)
    # or on a quiet frame this long after the last reference while every tap's departure stays
    # within a third of departure_kpa: a departure is then judged against the pressure change
    # since a recent still frame, not since the start of a long wind
    quiet_anchor_s: float = 10.0
    # a piston lagging while its pressure follows the others' (a seized seal, a valve closed on the
    # cylinder's side of the tap, a blocked hose) raises only with position_lag: a healthy seal at
    # rest holds its piston the same way through a load change (its static friction takes the
    # force), so off by default; a departing pressure raises either way
    position_lag: bool = False
    equalize_raise_s: float = 1.0
    equalize_clear_s: float = 2.0
    equalize_min_frames: int = 5
    # oil_loss: the oil balance lost more than oil_band_m3 within oil_window_s
    oil_band_m3: float = 3e-5                    # 30 mL
    oil_window_s: float = 120.0
    oil_expansion_per_k: float = OIL_EXPANSION_PER_K
    oil_volume_m3: float | None = None           # the trapped oil; None: unknown, no thermal correction
    oil_raise_s: float = 2.0
    oil_clear_s: float = 30.0
    oil_min_frames: int = 10
    # rope_adjust: rests (|speed| <= rest_speed_mm_s for rest_s) per wind; raise when a piston's
    # trend reaches its margin within adjust_winds winds
    rest_speed_mm_s: int = 5
    rest_s: float = 3.0
    rest_skip_s: float = 1.0                     # the bounce after the stop is not averaged
    adjust_winds: float = 10.0
    adjust_clear_winds: float = 15.0
    adjust_keep: int = 20                        # rests kept for the trend
    wind_min_m: float = 5.0                      # a rest this close to the one before is the same landing
    adjust_min_rests: int = 4
    adjust_trend_min_m: float = 5e-5             # per wind: slower is no trend

    def __post_init__(self) -> None:
        for name in ("stroke_hysteresis_m", "stroke_clear_s", "displacement_noise_m", "move_sigmas",
                     "move_min_m", "departure_kpa", "departure_frac", "reanchor_m", "anchor_max_s",
                     "equalize_raise_s", "equalize_clear_s", "oil_band_m3", "oil_window_s",
                     "oil_expansion_per_k", "oil_raise_s", "oil_clear_s", "rest_s", "rest_skip_s",
                     "adjust_winds", "adjust_clear_winds", "adjust_trend_min_m", "wind_min_m"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"equalizer.{name}: must be a finite number >= 0, got {v!r}")
        if not 1.0 <= self.lag_growth <= 10.0:
            raise ValueError(f"equalizer.lag_growth: must be 1..10, got {self.lag_growth!r}")
        if not 0 < self.seized_ratio < self.lag_ratio < self.follow_ratio <= 1:
            raise ValueError("equalizer: needs 0 < seized_ratio < lag_ratio < follow_ratio <= 1, got "
                             f"{self.seized_ratio}, {self.lag_ratio}, {self.follow_ratio}")
        if self.samples_per_frame < 1 or self.adjust_keep < 2 or self.adjust_min_rests < 2:
            raise ValueError("equalizer: samples_per_frame >= 1, adjust_keep and adjust_min_rests >= 2")
        if self.adjust_clear_winds < self.adjust_winds:
            raise ValueError("equalizer.adjust_clear_winds: must be at least adjust_winds")
        if self.margin_m is not None and not (math.isfinite(self.margin_m) and self.margin_m >= 0):
            raise ValueError(f"equalizer.margin_m: must be >= 0, got {self.margin_m!r}")
        for name in ("areas_m2", "stroke_m", "compliance_m_per_pa"):
            if any(not math.isfinite(v) or v < 0 for v in getattr(self, name)):
                raise ValueError(f"equalizer.{name}: must be finite and >= 0")
        # per rope of stroke_m: (in the low margin at or below, in the high margin at or above, clear
        # above, clear below), m; derived once (not a field: equality and repr stay the settings')
        bounds = ()
        if self.margin_m is not None:
            m, h = self.margin_m, self.stroke_hysteresis_m
            bounds = tuple((-st / 2 + m, st / 2 - m, -st / 2 + m + h, st / 2 - m - h) if st else None
                           for st in self.stroke_m)
        object.__setattr__(self, "_bounds", bounds)

    def per_rope(self, values: tuple[float, ...], i: int) -> float | None:
        """Rope i's figure (the last one for more ropes than figures); None when unknown."""
        if not values:
            return None
        return values[i] if i < len(values) else values[-1]

    @property
    def motion_sigma_m(self) -> float:
        """The rms noise of a difference of two frame means of a position."""
        return self.displacement_noise_m / math.sqrt(self.samples_per_frame) * math.sqrt(2.0)

    @property
    def motion_tolerance_m(self) -> float:
        """The largest disagreement between a healthy rope's reported motion and the others': each
        frame's position is rounded to position_step_m (a difference of two: up to one step off, the
        others' median as much), plus move_sigmas times the noise of a difference of two frame means."""
        return max(self.move_min_m, 2.0 * self.position_step_m + self.move_sigmas * self.motion_sigma_m)


class Continuity:
    """Whether a node's frames follow on: a new boot (seq's boot counter) or a gap of more than
    GAP_S in node time (modulo 2**32) breaks a tracker's reference."""

    GAP_S = 2.0
    __slots__ = ("last_ms", "boot")

    def __init__(self) -> None:
        self.last_ms: int | None = None
        self.boot: int | None = None

    def broken(self, frame: Frame) -> bool:
        boot = frame.seq >> SEQ_BOOT_SHIFT
        out = self.last_ms is not None and (
            boot != self.boot or ((frame.time_ms - self.last_ms) % (1 << 32)) / 1000.0 > self.GAP_S)
        self.last_ms, self.boot = frame.time_ms, boot
        return out


def positions(frame: Frame) -> list[float | None]:
    """Each rope's piston position (m) a judge may use: None where the frame has none (version 2,
    no healthy sample) or the rope's displacement channel faulted in the window."""
    out: list[float | None] = []
    for i, r in enumerate(frame.ropes):
        pos = getattr(r, "pos_01mm", POS_ABSENT)
        if pos == POS_ABSENT or frame.fault_mask >> (DISPLACEMENT_SHIFT + i) & 1:
            out.append(None)
        else:
            out.append(pos * 1e-4)
    return out


def has_positions(frame: Frame) -> bool:
    """The frame's layout carries piston positions (version 3 and later)."""
    return frame.version >= 3


# ------------------------------------------------------------------ stroke limit


class StrokeRope(NamedTuple):
    """One rope's stroke check in a frame: `end` "retracted" (low x) or "extended" (high x) when
    the piston is within the margin of it, else None; `clear`: far enough from both ends (margin
    plus hysteresis, the node's mask clear) for the alarm to clear."""

    end: str | None
    pos_m: float | None
    clear: bool


def stroke_check(frame: Frame, s: EqualizerSettings,
                 xs: list[float | None] | None = None) -> list[StrokeRope | None]:
    """Per rope: the stroke check, None for a rope not judged (no position, displacement fault).
    `xs`: the frame's `positions` when the caller has them."""
    out: list[StrokeRope | None] = []
    mask = getattr(frame, "stroke_mask", 0)
    bounds = s._bounds  # type: ignore[attr-defined]
    nb = len(bounds)
    for i, pos in enumerate(positions(frame) if xs is None else xs):
        if pos is None:
            out.append(None)
            continue
        if mask:
            low = bool(mask >> (STROKE_LOW_SHIFT + i) & 1)
            high = bool(mask >> (STROKE_HIGH_SHIFT + i) & 1)
        else:
            low = high = False
        b = bounds[i] if i < nb else (bounds[-1] if nb else None)
        clear = not (low or high)
        if b is not None:
            low = low or pos <= b[0]
            high = high or pos >= b[1]
            clear = clear and b[2] < pos < b[3]
        end = ("extended" if pos >= 0 else "retracted") if (low and high) else \
              "retracted" if low else "extended" if high else None
        out.append(StrokeRope(end, pos, clear and end is None))
    return out


# ------------------------------------------------------------------ not equalizing


class Participation(NamedTuple):
    """One rope's share of the oil's motion since the tracker's reference (a quiet frame before
    the load change). `lags`: the others moved beyond the threshold and this rope at most
    `lag_ratio` of it; `follows`: at least `follow_ratio` of it; neither: no evidence (no load
    change yet). `cause` names what the pressure and the position tell apart. The lag must pass
    `EqualizerSettings.motion_tolerance_m` and hold while the others' motion grows `lag_growth`
    fold: with the frame's 0.1 mm positions and k = 0.3 um/kPa a seized seal shows once the others
    moved about 0.5 mm (a load change of about 1.8 MPa)."""

    lags: bool
    follows: bool
    ratio: float | None          # own motion / the others' (median) motion
    own_m: float
    others_m: float
    departure_kpa: float         # own pressure change less the others' (median)
    others_kpa: float            # the others' pressure change
    cause: str


class EqualizingTracker:
    """Per node: each rope's piston motion against the others' over a load change (module doc).

    The reference is one frame's positions and pressures; the motion since it is judged each
    frame. It moves on (a new reference) once the others have moved `reanchor_m` with no rope
    lagging, every `anchor_max_s` (so a rope that lagged is judged afresh), when the set of judged ropes changes,
    after a node reset or a gap in the frames. Healthy pistons move alike: each by its
    compression `k dp` and the oil that flows between them (a balancing stroke moves one piston
    far and the others back by its volume: a rope moving more than the others is equalizing).
    So a rope is judged against the others' motion, never the rope alone: it lags when it moved
    less than the least moved of them (all one way) by the tolerance; it follows when it moved
    with their median.
    """

    OFFSET_FRAMES = 5
    QUIET_S = 1.0

    def __init__(self, s: EqualizerSettings) -> None:
        self.s = s
        self._thr = s.motion_tolerance_m
        self._still = s.position_step_m + 3.0 * s.motion_sigma_m    # "did not move", at the frame's resolution
        self._k_kpa: list[float] = []          # per rope: k in m per kPa
        # each rope's pressure less the others' median, over the last OFFSET_FRAMES quiet frames: the
        # reference's is their median, so a flow transient in the reference frame is not a departure
        self._offs: deque[list[float | None]] = deque(maxlen=self.OFFSET_FRAMES)
        self._offs_any: deque[list[float | None]] = deque(maxlen=self.OFFSET_FRAMES)  # quiet or not
        # (now_s, positions) of the last QUIET_S and one frame before: a frame is quiet when no piston
        # moved beyond the frame's resolution (`_still`) since QUIET_S ago (no flow parts the taps)
        self._xhist: deque[tuple[float, list[float | None]]] = deque(maxlen=128)
        self._ref_off: list[float | None] = []
        self._ref_x: list[float | None] = []
        self._ref_p: list[float | None] = []
        self._ref_s: float | None = None
        self._ref_usable: list[bool] = []      # which ropes the reference judges
        self._lo: list[float] = []             # each rope's own motion since the reference: its range
        self._hi: list[float] = []
        self._first: list[float | None] = []    # the others' motion when this rope's lag began
        self._continuity = Continuity()
        self.last: list[Participation | None] = []

    def reset(self) -> None:
        self._ref_s = None
        self._offs.clear()
        self._offs_any.clear()
        self._xhist.clear()

    def update(self, frame: Frame, now_s: float, skip: Sequence[bool] = (),
               xs: list[float | None] | None = None) -> list[Participation | None]:
        """Take the node's next frame; per rope its participation, None where not judged (no
        position or pressure, `skip[i]`: e.g. the piston in its stroke margin). `xs`: the frame's
        `positions` when the caller has them."""
        s = self.s
        n = len(frame.ropes)
        if self._continuity.broken(frame):
            self.reset()
        if xs is None:
            xs = positions(frame)
        absent = L.RAW_KPA_ABSENT
        ps = [None if r.raw_kpa == absent else float(r.raw_kpa) for r in frame.ropes]
        usable = [x is not None and p is not None for x, p in zip(xs, ps)]
        if len(self._k_kpa) != n:
            self._k_kpa = [(s.per_rope(s.compliance_m_per_pa, i) or 0.0) * 1000.0 for i in range(n)]
            self._offs.clear()
            self._offs_any.clear()
        idx = [i for i in range(n) if usable[i]]
        off: list[float | None] = [None] * n
        if len(idx) >= 2:
            for i, m in zip(idx, _medians_without([ps[i] for i in idx])):
                off[i] = ps[i] - m
        quiet, quiet_of, flowing_of = self._motion(n, xs, usable, idx, now_s)
        if quiet:
            self._offs.append(off)
        self._offs_any.append(off)
        if self._ref_s is None or usable != self._ref_usable:
            self._anchor(xs, ps, usable, now_s)
            self.last = [None] * n
            return self.last
        if len(idx) < 2:
            self.last = [None] * n
            return self.last
        ref_x, ref_p = self._ref_x, self._ref_p
        dx: list = [None] * n
        dp: list = [None] * n
        for i in idx:
            dx[i] = xs[i] - ref_x[i]
            dp[i] = ps[i] - ref_p[i]
        thr = self._thr
        if any(skip):
            # a piston at its end: the equalizer's motion is not its own (the stopped cylinder takes
            # no oil, the others part), so nobody is judged, and the reference restarts after
            self._anchor(xs, ps, usable, now_s)
            self.last = [Participation(False, False, None, 0.0, 0.0, 0.0, 0.0, "") if u else None for u in usable]
            return self.last
        moved = 0.0
        lo_, hi_ = self._lo, self._hi
        for i in idx:
            d = dx[i]
            if d < lo_[i]:
                lo_[i] = d
            elif d > hi_[i]:
                hi_[i] = d
            if abs(d) > moved:
                moved = abs(d)
        # a pressure departing from the others' (a tap reading a cylinder cut off from the manifold);
        # not a frozen transmitter (its own pressure still: SENSOR STUCK). A cut-off cylinder's piston
        # moves only by its own oil's compression (k times its own pressure change), give or take the
        # frame's resolution (`still`, not the motion tolerance: a slow balancing stroke under the
        # tolerance parts the taps by tens of kPa with its flow): one that moved more, or went and
        # came back, shares the manifold's oil, and is not cut off. Judged only while the others'
        # pistons moved alike within QUIET_S (no oil flowing between them: a slip's flow parts the
        # taps by 100 kPa and more while it lasts), against the offsets of frames where all moved
        # alike (a reference taken within a slip would make the taps' return to the manifold's
        # pressure look a departure)
        ops: list = [None] * n                 # each rope's others' pressure change (their median)
        for i, m in zip(idx, _medians_without([dp[i] for i in idx])):
            ops[i] = m
        departing = self._departing(idx, quiet_of, off, dx, dp, ops)
        if moved < thr and not departing:   # no piston moved beyond the tolerance: the usual case
            self.last = [Participation(False, False, None, dx[i], 0.0, 0.0, 0.0, "") if usable[i] else None
                         for i in range(n)]
            for i in range(n):
                if self._first[i] is not None:
                    self._first[i] = None
            if now_s - self._ref_s >= s.anchor_max_s or self._settled(quiet, idx, off, now_s):
                self._anchor(xs, ps, usable, now_s)
            return self.last
        out, moved_all, any_lag = self._participation(n, usable, idx, dx, dp, ops, departing, flowing_of)
        self.last = out
        if ((moved_all >= s.reanchor_m or self._settled(quiet, idx, off, now_s)) and not any_lag) \
                or now_s - self._ref_s >= s.anchor_max_s:
            self._anchor(xs, ps, usable, now_s)
        return out

    def _settled(self, quiet: bool, idx, off, now_s: float) -> bool:
        """A quiet frame `quiet_anchor_s` or more after the reference with every judged tap within a
        third of `departure_kpa` of its reference offset: a new reference loses no evidence (a
        departure building slowly holds the old one until it is judged)."""
        s = self.s
        if not quiet or self._ref_s is None or now_s - self._ref_s < s.quiet_anchor_s:
            return False
        lim = s.departure_kpa / 3.0
        ref_off = self._ref_off
        for i in idx:
            o, r = off[i], ref_off[i] if i < len(ref_off) else None
            if o is None or r is None or abs(o - r) >= lim:
                return False
        return True

    def _motion(self, n: int, xs, usable, idx, now_s: float) -> tuple[bool, list[bool], list[bool]]:
        """The pistons' motion over the last QUIET_S (the history `_xhist` taken this frame): whether
        all moved alike, per rope whether the others than it did, and whether they did not (known)."""
        hist = self._xhist
        hist.append((now_s, xs))
        while len(hist) > 2 and now_s - hist[1][0] >= self.QUIET_S:
            hist.popleft()
        # the pistons' motion over the last QUIET_S: where they moved alike (within the frame's
        # resolution) no oil flowed between the cylinders, only the compression's, alike on every tap
        quiet = False                          # all moved alike
        quiet_of = flowing_of = [False] * n    # the others than this rope did; they did not (known)
        t_old, x_old = hist[0]
        if now_s - t_old >= self.QUIET_S and len(x_old) == n and len(idx) >= 2 and all(
                x_old[i] is not None for i in idx):
            mv = [xs[i] - x_old[i] for i in idx]
            st_ = self._still
            quiet = max(mv) - min(mv) <= st_
            if quiet or len(mv) == 2:          # (one other rope: alike with itself)
                quiet_of = usable
            else:
                srt = sorted(zip(mv, idx))
                lo_i, hi_i = srt[0][1], srt[-1][1]
                quiet_of = [False] * n
                for i in idx:
                    top = srt[-2][0] if i == hi_i else srt[-1][0]
                    bot = srt[1][0] if i == lo_i else srt[0][0]
                    quiet_of[i] = top - bot <= st_
                flowing_of = [u and not q for u, q in zip(usable, quiet_of)]
        return quiet, quiet_of, flowing_of

    def _departing(self, idx, quiet_of, off, dx, dp, ops) -> dict[int, tuple[float, float]]:
        """The ropes whose pressure departs from the others' (see `update`): rope -> (departure, the
        others' pressure change), judged where the others moved alike."""
        s = self.s
        still = self._still
        lo_, hi_ = self._lo, self._hi
        departing: dict[int, tuple[float, float]] = {}
        ref_off = self._ref_off
        dep_kpa, dep_frac, k_kpa = s.departure_kpa, s.departure_frac, self._k_kpa
        for i in idx:
            if not quiet_of[i]:
                continue
            op = ops[i]
            oi, ri = off[i], ref_off[i]
            dep = oi - ri if oi is not None and ri is not None else dp[i] - op
            if (abs(dep) > max(dep_kpa, dep_frac * abs(op))
                    and abs(dp[i]) >= max(dep_kpa / 3.0, 0.25 * abs(op))):
                squeeze = k_kpa[i] * abs(dp[i]) + still
                if abs(dx[i]) <= squeeze and hi_[i] - lo_[i] <= squeeze:
                    departing[i] = (dep, op)
        return departing

    def _participation(self, n: int, usable, idx, dx, dp, ops, departing,
                       flowing_of) -> tuple[list[Participation | None], float, bool]:
        """Per rope its participation on a frame where a piston moved beyond the tolerance or a
        pressure departs; with the others' largest motion and whether any rope is held lagging."""
        s = self.s
        thr, still = self._thr, self._still
        meds: list = [None] * n                # each rope's others' motion (their median)
        for i, m in zip(idx, _medians_without([dx[i] for i in idx])):
            meds[i] = m
        by_abs = sorted(idx, key=lambda i: abs(dx[i]))
        least, second = by_abs[0], by_abs[1]
        out: list[Participation | None] = []
        moved_all = 0.0
        any_lag = False
        for i in range(n):
            if not usable[i]:
                out.append(None)
                continue
            own = dx[i]
            med = meds[i]
            op = ops[i]
            dep = dp[i] - op
            if abs(med) > moved_all:
                moved_all = abs(med)
            if i in departing:
                any_lag = True
                dep = departing[i][0]
                cause = (f"its pressure departs {dep:+.0f} kPa from the others' change ({op:+.0f} kPa) while its "
                         f"piston moved {own * 1e3:+.2f} mm against their {med * 1e3:+.2f} mm: its cylinder cut off "
                         "from the manifold (a stop valve closed between its pressure tap and the manifold), or its "
                         "pressure transmitter misreads")
                out.append(Participation(True, False, own / med if med else None, own, med, dep, op, cause))
                continue
            if abs(med) < thr:
                out.append(Participation(False, False, None, own, med, dep, op, ""))
                self._first[i] = None
                continue
            # following (the evidence that clears) only where its pressure was judged too: a frame
            # whose flow parts the taps shows no departure, and no return from one either
            follows = (abs(med) - abs(own) < 0.75 * thr and abs(own) / abs(med) >= s.follow_ratio
                       and not flowing_of[i])
            # against the least moved of the others: a seal at rest holds its piston a while, and
            # where some pistons hold while others slide, a held one is not the odd one out. So only
            # the least moved rope of all can lag (any other has one moved less than itself).
            ox = dx[second] if i == least else dx[least]
            if ox * med <= 0:
                ox = 0.0                   # the others moved different ways: a stroke, no evidence
            if i != least or abs(ox) < thr:
                out.append(Participation(False, follows, own / med, own, med, dep, op, ""))
                self._first[i] = None
                continue
            ratio = own / ox
            share = abs(own) / abs(ox)
            gap = abs(ox) - abs(own)
            # a piston that moved against the others, or went and came back since the reference,
            # slid: a balancing stroke, the equalizer working. One that does not take part stays, or
            # moves one way only with its own oil's compression.
            slid = (own * math.copysign(1.0, ox) < -still
                    or self._hi[i] - self._lo[i] > abs(own) + still)
            lags = gap >= thr and share <= s.lag_ratio and not slid
            # the lag must hold while the others' motion grows lag_growth-fold: a balancing stroke
            # against the oil's motion leaves a fixed lag, which the growing motion outgrows
            if not lags:
                if gap < 0.5 * thr or slid:
                    self._first[i] = None      # clearly not lagging (a flicker at the edge keeps it)
            else:
                any_lag = any_lag or s.position_lag   # held: the reference kept while it is judged
                if self._first[i] is None:
                    self._first[i] = abs(ox)
            lags = lags and abs(ox) >= s.lag_growth * self._first[i] - 1e-12 and s.position_lag
            cause = ""
            if lags:
                if abs(own) <= max(s.seized_ratio * abs(ox), still):
                    cause = (f"its piston did not move ({own * 1e3:+.2f} mm) while the others moved "
                             f"{ox * 1e3:+.2f} mm or more and its pressure followed theirs: a seized seal (or its "
                             "cylinder's oil shut in at the cylinder)")
                else:
                    cause = (f"its piston moved {own * 1e3:+.2f} mm, {share:.0%} of the others' {ox * 1e3:+.2f} mm or more, "
                             "while its pressure followed theirs: its oil does not reach the manifold (a stop "
                             "valve closed on the cylinder's side of the tap, or a blocked hose)")
            out.append(Participation(lags, follows and not lags, ratio, own, ox, dep, op, cause))
        return out, moved_all, any_lag

    def _anchor(self, xs, ps, usable, now_s: float) -> None:
        self._ref_x = [x if u else None for x, u in zip(xs, usable)]
        self._ref_p = [p if u else None for p, u in zip(ps, usable)]
        self._ref_usable = list(usable)
        self._ref_s = now_s
        ref_off: list[float | None] = []
        for i, u in enumerate(usable):
            # the quiet frames' (none yet: the last frames', quiet or not)
            offs = self._offs if any(i < len(o) and o[i] is not None for o in self._offs) else self._offs_any
            v = sorted(o[i] for o in offs if i < len(o) and o[i] is not None) if u else []
            ref_off.append(v[len(v) // 2] if v else None)
        self._ref_off = ref_off
        self._lo = [0.0] * len(xs)
        self._hi = [0.0] * len(xs)
        self._first = [None] * len(xs)


# ------------------------------------------------------------------ oil loss


class OilState(NamedTuple):
    """The oil balance: `lost_m3` within the window (`window_s` long, up to now), the rate over
    the window's last quarter, the band it is judged against (the setting plus the thermal allowance), the temperature used."""

    lost_m3: float
    rate_m3_s: float
    window_s: float
    band_m3: float
    balance_m3: float            # the oil lost since the tracker's start (or reset)


class OilTracker:
    """Per node: the trapped oil's balance (module doc).

    `balance = sum A_i (x_i - k_i p_i) + alpha V_oil (T - T_0)`: with no oil lost it stays
    constant through load changes (the compression is `k p`) and temperature changes (with the
    frame's oil temperature and the oil volume `oil_volume_m3` known; without them the term is
    left out); oil lost pulls the pistons out and raises it. Judged over a sliding window (a
    fixed ring of entries) against a band, so the slow drift the station cannot explain (a
    temperature change: 0.1 K within the window expands 12 L of oil by under 1 mL; k's error)
    never adds up over days. Needs the cylinder areas and the compliance (without `k` a wind's pressure
    change alone moves the pistons by about a millimetre: tens of mL), and every rope's position
    and pressure; a frame without them restarts the window."""

    SLOTS = 24

    def __init__(self, s: EqualizerSettings, n_ropes: int | None = None) -> None:
        self.s = s
        self._ring: deque[tuple[float, float, float | None]] = deque(maxlen=self.SLOTS + 1)
        self._continuity = Continuity()
        self._ak: list[tuple[float, float]] = []   # per rope: area, k per kPa
        self._t0: float | None = None     # oil temperature at the start, C
        self._b0: float | None = None
        self.last: OilState | None = None

    def reset(self) -> None:
        self._ring.clear()
        self._t0 = self._b0 = None

    def update(self, frame: Frame, now_s: float, xs: list[float | None] | None = None) -> OilState | None:
        """Take the node's next frame (`xs`: its `positions` when the caller has them)."""
        s = self.s
        n = len(frame.ropes)
        if self._continuity.broken(frame):
            self.reset()
        if not s.areas_m2 or not any(s.compliance_m_per_pa) or n == 0:
            self.last = None
            return None
        if xs is None:
            xs = positions(frame)
        if len(self._ak) != n:
            self._ak = [(s.per_rope(s.areas_m2, i) or 0.0, (s.per_rope(s.compliance_m_per_pa, i) or 0.0) * 1000.0)
                        for i in range(n)]
        bal = 0.0
        for (a, k_kpa), x, r in zip(self._ak, xs, frame.ropes):
            if x is None or r.raw_kpa == L.RAW_KPA_ABSENT:
                self.reset()
                self.last = None
                return None
            bal += a * (x - k_kpa * r.raw_kpa)
        temp = None if frame.oil_temp_cc == L.OIL_TEMP_ABSENT else frame.oil_temp_cc / 100.0
        vol = s.oil_volume_m3
        if vol is None:
            temp = None          # the expansion unknown: a slow temperature change within the window is negligible
        if temp is not None:
            if self._t0 is None:
                self._t0 = temp
            bal += s.oil_expansion_per_k * vol * (temp - self._t0)
        if self._b0 is None:
            self._b0 = bal
        ring = self._ring
        step = s.oil_window_s / self.SLOTS
        if not ring or now_s - ring[-1][0] >= step:
            ring.append((now_s, bal, temp))
        t_old, b_old, temp_old = ring[0]
        span = now_s - t_old
        lost = bal - b_old
        # the rate: over the last quarter of the window (a leak that began within it shows its own rate)
        t_r, b_r = t_old, b_old
        for t_e, b_e, _ in ring:
            if now_s - t_e < s.oil_window_s / 4:
                break
            t_r, b_r = t_e, b_e
        rate = (bal - b_r) / (now_s - t_r) if now_s > t_r else 0.0
        # the band: the setting, plus a quarter of the expansion the temperature's change within the
        # window makes (the oil volume's uncertainty)
        band = s.oil_band_m3
        if vol is not None and temp is not None and temp_old is not None:
            band += s.oil_expansion_per_k * vol * 0.25 * abs(temp - temp_old)
        self.last = OilState(lost, rate, span, band, bal - self._b0)
        return self.last


# ------------------------------------------------------------------ rope adjustment


class AdjustForecast(NamedTuple):
    """One rope's rest positions across winds: the least-squares trend (m per wind), the fitted
    position at the last wind, the end it heads for, and the winds left before it reaches
    that end's margin (0: already within; None: no trend)."""

    trend_m: float
    last_m: float
    end: str                 # "extended" (trend > 0) or "retracted"
    winds_left: float | None


def adjust_forecast(rests: Sequence[Sequence[float | None]], stroke_m: float | Sequence[float],
                    margin_m: float | None, min_winds: int = 3,
                    trend_min_m: float = 0.0) -> list[AdjustForecast | None]:
    """Per rope, from `rests` (per wind, oldest first, each a list of per-rope rest positions in m,
    None where unknown): the trend and the winds left before the piston reaches its margin
    (`stroke_m` per rope or one for all, end stops at +-stroke/2; `margin_m` None: 0). None for a
    rope with fewer than `min_winds` rests. A trend slower than `trend_min_m` per wind gives
    winds_left None (no end in sight). ValueError for a stroke or margin that is not positive."""
    n = max((len(r) for r in rests), default=0)
    strokes = [stroke_m] * n if isinstance(stroke_m, (int, float)) else list(stroke_m)
    margin = 0.0 if margin_m is None else float(margin_m)
    if margin < 0 or not math.isfinite(margin):
        raise ValueError(f"margin_m: must be >= 0, got {margin_m!r}")
    out: list[AdjustForecast | None] = []
    for i in range(n):
        pts = [(k, float(w[i])) for k, w in enumerate(rests) if i < len(w) and w[i] is not None]
        if len(pts) < max(2, min_winds):
            out.append(None)
            continue
        ks = [k for k, _ in pts]
        km = sum(ks) / len(ks)
        xm = sum(x for _, x in pts) / len(pts)
        sxx = sum((k - km) ** 2 for k in ks)
        slope = sum((k - km) * (x - xm) for k, x in pts) / sxx if sxx > 0 else 0.0
        last_k = len(rests) - 1
        last = xm + slope * (last_k - km)
        stroke = strokes[i] if i < len(strokes) else (strokes[-1] if strokes else None)
        if stroke is None or not (stroke > 0 and math.isfinite(stroke)):
            raise ValueError(f"stroke_m: rope {i + 1} needs a positive stroke, got {stroke!r}")
        limit = stroke / 2.0 - margin
        end = "extended" if slope > 0 else "retracted"
        if abs(slope) <= trend_min_m or slope == 0.0:
            left = None
        else:
            room = limit - last if slope > 0 else last + limit
            left = max(0.0, room / abs(slope))
        out.append(AdjustForecast(slope, last, end, left))
    return out


class RestTracker:
    """Per node: each piston's mean position over every rest (|speed| <= rest_speed_mm_s for at
    least rest_s, the first rest_skip_s of bounce left out), one per wind (a later rest within
    wind_min_m of the one before, at the same landing, replaces it), the last adjust_keep kept. With a compliance the positions are taken at the first rest's pressure (`x - k (p - p_0)`),
    so a loaded and an empty landing compare. A rope without a position in any frame of the rest
    has None for it."""

    def __init__(self, s: EqualizerSettings) -> None:
        self.s = s
        self.rests: deque[list[float | None]] = deque(maxlen=s.adjust_keep)
        self._since: float | None = None        # the rest began
        self._sum: list[float] = []
        self._cnt: list[int] = []
        self._bad: list[bool] = []
        self._psum: list[float] = []
        self._p0: list[float | None] = []
        self._depth_mm: int | None = None       # where the last rest was recorded
        self._here_mm = 0                       # the cage's depth in the rest now

    def update(self, frame: Frame, now_s: float, xs: list[float | None] | None = None) -> bool:
        """Take a frame; True when a rest just ended (a new entry in `rests`)."""
        s = self.s
        n = len(frame.ropes)
        still = abs(frame.speed_mm_s) <= s.rest_speed_mm_s
        if still:
            self._here_mm = frame.depth_mm
            if self._since is None:
                self._since = now_s
                self._sum, self._cnt, self._bad = [0.0] * n, [0] * n, [False] * n
                self._psum = [0.0] * n
            if now_s - self._since >= s.rest_skip_s and len(self._sum) == n:
                for i, x in enumerate(positions(frame) if xs is None else xs):
                    kpa = frame.ropes[i].raw_kpa
                    if x is None or kpa == L.RAW_KPA_ABSENT:
                        self._bad[i] = True
                    else:
                        self._sum[i] += x
                        self._psum[i] += kpa * 1000.0
                        self._cnt[i] += 1
            return False
        ended = self._since is not None and now_s - self._since >= s.rest_s and any(self._cnt)
        if ended:
            if len(self._p0) != len(self._sum):
                self._p0 = [None] * len(self._sum)
            rest: list[float | None] = []
            for i, (sx, c, bad) in enumerate(zip(self._sum, self._cnt, self._bad)):
                if bad or not c:
                    rest.append(None)
                    continue
                x, p = sx / c, self._psum[i] / c
                k = s.per_rope(s.compliance_m_per_pa, i) or 0.0
                if self._p0[i] is None:
                    self._p0[i] = p
                rest.append(x - k * (p - self._p0[i]))
            # one rest per wind: another rest at the same landing (a loading between, the cage
            # creeping) replaces the one before, so the trend is per wind
            if (self.rests and self._depth_mm is not None
                    and abs(self._here_mm - self._depth_mm) < s.wind_min_m * 1000.0):
                self.rests[-1] = rest
            else:
                self.rests.append(rest)
            self._depth_mm = self._here_mm
        self._since = None
        return ended

    def forecast(self) -> list[AdjustForecast | None]:
        s = self.s
        if not s.stroke_m or not self.rests:
            return []
        return adjust_forecast(list(self.rests), s.stroke_m, s.margin_m, s.adjust_min_rests, s.adjust_trend_min_m)


def _medians_without(vals: list[float]) -> list[float]:
    """For each of `vals` (two or more), the median of the others: `_median_without` of each, the
    sort done once (and for four values, the usual ropes, without a search)."""
    v = sorted(vals)
    if len(v) == 4:
        v1, v2 = v[1], v[2]
        return [v1 if x > v1 else v2 for x in vals]
    return [_median_without(v, x) for x in vals]


def _median_without(v: list[float], x: float) -> float:
    """The median of sorted `v` with one `x` (an element of it) left out."""
    k = bisect.bisect_left(v, x)
    m = len(v) - 1

    def at(j: int) -> float:
        return v[j] if j < k else v[j + 1]
    return at(m // 2) if m % 2 else (at(m // 2 - 1) + at(m // 2)) / 2.0

