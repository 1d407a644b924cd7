"""How far each rope's true tension may be from the node's compensated tension: the band.

The node's tension is `T^ = p A + F^` (docs/model.md, "Piston equation"), with `F^` the
seal friction its LuGre observer estimates. The cylinders share one oil manifold, so
`p A` hardly differs between ropes and the rope-imbalance alarm rests on `F^` alone.
`SealBandTracker` bounds the error of `F^` from what the host sees in each frame
(docs/operator.md, "The band"):

- the physical range: a seal holds at most its static friction, so the true friction
  lies in `[-S, +S]`, `S = (1 + band_margin) Fs(p) + f` with the floor `f = 2 r`
  (`r`: the friction fit's residual: `physical.friction.residual` in N, else the larger
  of `physical.friction_residual_frac`'s sliding and pre-sliding parts times `Fs(p)`
  (`ropemon fit-friction`), else 5 % of `Fc(p)`); the true tension in `[pA - S, pA + S]`;
- with `band_anchor` (off by default: without it no rope is ever anchored and the band is
  the whole physical range), the anchor `F_a`: the estimate when it was last trustworthy, i.e. saturated
  (`|F^| >= band_saturation Fc(p)`: the node believes the seal slides) and driven there:
  while it stayed saturated on one side, the rope's `p A` moved that way (the sliding
  direction) by at least `band_anchor_travel S`. A flip of the estimate, or its
  relaxation towards 0, while the pressure barely moves (pre-sliding, where seal models
  differ) does not move the anchor;
- the band: `u = max(f, band_gain |F^ - F_a|)`, the friction interval
  `[F^ - u, F^ + u]` cut to `[-S, +S]` (so it covers the anchor for a gain >= 1, and
  never leaves the physical range). Without an anchor (start, after a fault, a node
  reset or a gap in the frames longer than `band_blind_s`) it is the whole `[-S, +S]`:
  the rope is not vouched for. A rope faulted in the frame (`fault_mask`) gets the whole
  range too; an absent rope (no tension) gets `[pA - S, pA + S]` at the median pressure
  of the others (the manifold is shared).

The interval is asymmetric after the cut; `update` returns the symmetric band
`u_i = max(T_hi - T^, T^ - T_lo)` per rope and `intervals` the interval itself.
Between frames `intervals(age_s)` widens every interval linearly to the whole physical
range over `band_blind_s`.

Deviation bounds (`deviation_bounds`): rope i's deviation `d_i = T_i / mean_j(T_j) - 1 =
n T_i / (T_i + sum_{j!=i} T_j) - 1` rises with `T_i` and falls with every other `T_j`,
so over the intervals its extremes are exact at the corners:
`d_max = n b_i / (b_i + sum_{j!=i} a_j) - 1`, `d_min = n a_i / (a_i + sum_{j!=i} b_j) - 1`
(`[a_j, b_j]` the tension intervals, `a_j >= 0`: a rope does not push). To first order
with `|e_j| <= u_j` this is `|d_i| <= |d^_i| + ((1 - (1 + d^_i)/n) u_i
+ (1 + d^_i)/n sum_{j!=i} u_j) / mean(T^)`, at most `|d^_i| + (u_i + (1 + d^_i) mean_j u_j) / mean(T^)`.
`d^_i` itself is the node's deviation over the ropes that have a tension (as the DEVIATION alarm).

No wall clock: time is the frames' node time, so a sequence of frames replays the same.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, NamedTuple, Sequence

from ropemon.station.protocol import DAN_TO_N, Frame, L

SEQ_BOOT_SHIFT = 20   # seq = (boot << 20) | count (docs/protocol.md)

#: The band's parameters, host only, in node.json's `physical` (docs/config.md), with defaults.
# Anchoring is off by default: on simulated hoists whose ropes part through the wind the node's
# saturated estimate can sit on the wrong side of the seal, and anchoring on it left ropes beyond
# the limit silent (docs/accuracy.md, "The envelope"); without it the band is the
# seal's physical range. The margin covers a seal's break force above the test bed's sample
# (the population draws each rope's seal within +-15 % of the type's).
DEFAULTS = {
    "band_anchor": False,        # take the node's saturated, pressure-driven estimate as the seal's force
    "band_margin": 0.25,         # the true static friction may exceed the fit's Fs(p) by this fraction
    "band_gain": 1.0,            # c in u = max(f, c |F^ - F_a|); >= 1 keeps the anchor inside
    "band_saturation": 0.7,      # |F^| >= this x Fc(p): the node believes the seal slides
    "band_anchor_travel": 0.25,  # p A moved this many S in the sliding direction while saturated
    "band_blind_s": 2.0,         # gap after which the anchor is dropped; the widening between frames
}
RESIDUAL_FRAC_OF_FC = 0.05       # the fit's residual when physical.friction.residual is absent
_RANGES = {
    "band_margin": (0.0, 2.0),
    "band_gain": (0.0, 10.0),
    "band_saturation": (0.1, 1.0),
    "band_anchor_travel": (0.0, 100.0),
    "band_blind_s": (0.1, 600.0),
}


class Line(NamedTuple):
    """A friction line X(p) = intercept + slope p (p in MPa, a float or an array). The one
    evaluation of the seal's pressure lines: ropemon.commission.seal uses it too."""

    intercept: float
    slope: float      # per MPa

    def at(self, p_mpa: float) -> float:
        return self.intercept + self.slope * p_mpa


def _number(v, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{where}: {v!r} is not a number")
    return float(v)


@dataclass(frozen=True)
class BandParams:
    """What the band needs from node.json's `physical` section (docs/config.md)."""

    areas_m2: tuple[float, ...]
    fs: Line
    fc: Line
    p_max_mpa: float | None = None      # friction lines held above this (friction_p_max_MPa)
    residual_n: float | None = None     # friction fit residual, N
    residual_frac_fs: float | None = None  # else: this fraction of Fs(p); else RESIDUAL_FRAC_OF_FC x Fc(p)
    anchor: bool = DEFAULTS["band_anchor"]
    margin: float = DEFAULTS["band_margin"]
    gain: float = DEFAULTS["band_gain"]
    saturation: float = DEFAULTS["band_saturation"]
    anchor_travel: float = DEFAULTS["band_anchor_travel"]
    blind_s: float = DEFAULTS["band_blind_s"]

    @classmethod
    def from_physical(cls, phys: dict) -> "BandParams | None":
        """From node.json's `physical`; None when it has no friction lines or cylinder areas
        (then there is no band: the host cannot tell friction from pressure)."""
        fr = phys.get("friction")
        area = phys.get("cylinder_area_m2")
        if not isinstance(fr, dict) or area is None:
            return None
        ropes = int(phys.get("ropes", len(area) if isinstance(area, list) else 4))
        areas = [area] * ropes if not isinstance(area, list) else area
        areas = tuple(_number(a, "physical.cylinder_area_m2") for a in areas)
        if not areas or min(areas) <= 0:
            raise ValueError("physical.cylinder_area_m2: areas must be positive")
        try:
            fs = Line(_number(fr["Fs"]["intercept"], "physical.friction.Fs"), _number(fr["Fs"]["slope"], "physical.friction.Fs"))
            fc = Line(_number(fr["Fc"]["intercept"], "physical.friction.Fc"), _number(fr["Fc"]["slope"], "physical.friction.Fc"))
        except (KeyError, TypeError):
            raise ValueError("physical.friction: needs Fs and Fc as {intercept, slope}") from None
        res = fr.get("residual")
        if res is not None:
            res = _number(res, "physical.friction.residual")
            if res < 0:
                raise ValueError(f"physical.friction.residual: {res} N is negative")
        frac = phys.get("friction_residual_frac")
        if isinstance(frac, dict) and frac:
            frac = max(_number(v, "physical.friction_residual_frac") for v in frac.values())
            if frac < 0:
                raise ValueError(f"physical.friction_residual_frac: {frac} is negative")
        else:
            frac = None
        pmax = phys.get("friction_p_max_MPa")
        anchor = phys.get("band_anchor", DEFAULTS["band_anchor"])
        if not isinstance(anchor, bool):
            raise ValueError(f"physical.band_anchor: must be true or false, got {anchor!r}")
        kw = {"anchor": anchor}
        for key, (lo, hi) in _RANGES.items():
            v = _number(phys.get(key, DEFAULTS[key]), f"physical.{key}")
            if not lo <= v <= hi:
                raise ValueError(f"physical.{key}: {v} out of range {lo}..{hi}")
            kw[key.removeprefix("band_")] = v
        return cls(areas, fs, fc, None if pmax is None else _number(pmax, "physical.friction_p_max_MPa"),
                   res, frac, **kw)

    def limits(self, p_kpa: float) -> tuple[float, float, float]:
        """(S, Fc, f) in N at tap pressure p_kpa: the friction bound, the sliding friction, the floor."""
        p = max(0.0, p_kpa / 1000.0)
        if self.p_max_mpa is not None:
            p = min(p, self.p_max_mpa)
        fc = max(0.0, self.fc.at(p))
        fs = max(0.0, self.fs.at(p))
        if self.residual_n is not None:
            res = self.residual_n
        elif self.residual_frac_fs is not None:
            res = self.residual_frac_fs * fs
        else:
            res = RESIDUAL_FRAC_OF_FC * fc
        floor = 2.0 * res
        s = (1.0 + self.margin) * fs + floor
        return s, fc, floor


class RopeInterval(NamedTuple):
    """One rope's band in a frame, N. `t_hat` is the node's tension (for an absent rope: p A at
    the manifold's pressure); the true tension lies in [lo, hi]; vouched: an anchor backs it."""

    t_hat: float
    lo: float
    hi: float
    pa: float        # p A (N)
    s: float         # the friction bound S (N)
    vouched: bool
    present: bool = True   # the frame has a tension for the rope

    @property
    def u(self) -> float:
        return max(self.hi - self.t_hat, self.t_hat - self.lo)


class DeviationBand(NamedTuple):
    """A rope's deviation from the mean of the ropes: the node's `dev`, the extremes its
    band allows, and `band = max(|d_min|, |d_max|) - |dev|`: how far beyond |dev| it may reach."""

    dev: float
    d_min: float
    d_max: float

    @property
    def reach(self) -> float:
        return max(abs(self.d_min), abs(self.d_max))

    @property
    def band(self) -> float:
        return max(0.0, self.reach - abs(self.dev))


@dataclass
class _RopeRun:
    anchor: float | None = None
    run_sign: int = 0              # side of the current saturated run (0: none)
    run_travel: float = 0.0        # p A moved in the run's sliding direction since it began (N)
    last_pa: float | None = None


class SealBandTracker:
    """Per node: each rope's band from its frames (module doc). Offline use:

        tracker = SealBandTracker(BandParams.from_physical(physical))
        for frame in frames:            # one node's frames in order
            u = tracker.update(frame)   # per rope, N (nan: a rope with no tension and no pressure to bound it)
    """

    def __init__(self, params: BandParams) -> None:
        self.p = params
        self._ropes: list[_RopeRun] = []
        self._last_ms: int | None = None
        self._last_boot: int | None = None
        self.last: list[RopeInterval] = []

    def reset(self) -> None:
        """Forget every anchor: no rope is vouched for until it is anchored again."""
        for r in self._ropes:
            r.anchor, r.run_sign, r.run_travel, r.last_pa = None, 0, 0.0, None

    def update(self, frame: Frame) -> list[float]:
        """Take the node's next frame; the band u_i (N) per rope."""
        if not frame.ropes:
            return []
        n = len(frame.ropes)
        while len(self._ropes) < n:
            self._ropes.append(_RopeRun())
        boot = frame.seq >> SEQ_BOOT_SHIFT
        if self._last_ms is not None:
            gap_s = ((frame.time_ms - self._last_ms) % (1 << 32)) / 1000.0
            # a node reset restarts its observer (boot counter up); a long gap hides what the seals did
            if boot != self._last_boot or gap_s > self.p.blind_s:
                self.reset()
        self._last_ms, self._last_boot = frame.time_ms, boot
        areas = self.p.areas_m2
        kpas = [r.raw_kpa for r in frame.ropes if r.raw_kpa != L.RAW_KPA_ABSENT]
        manifold_kpa = _median(kpas) if kpas else None
        out: list[RopeInterval] = []
        for i, rec in enumerate(frame.ropes):
            st = self._ropes[i]
            area = areas[i] if i < len(areas) else areas[-1]
            faulted = bool(frame.fault_mask & ((1 << i) | (1 << (4 + i))))
            if rec.mean_dan == L.TENSION_ABSENT or rec.raw_kpa == L.RAW_KPA_ABSENT:
                st.anchor, st.run_sign, st.run_travel, st.last_pa = None, 0, 0.0, None
                kpa = rec.raw_kpa if rec.raw_kpa != L.RAW_KPA_ABSENT else manifold_kpa
                if kpa is None:
                    out.append(RopeInterval(math.nan, -math.inf, math.inf, math.nan, math.inf, False, False))
                    continue
                pa = kpa * 1000.0 * area
                s, _, _ = self.p.limits(kpa)
                out.append(RopeInterval(pa, max(0.0, pa - s), pa + s, pa, s, False, False))
                continue
            pa = rec.raw_kpa * 1000.0 * area
            t_hat = rec.mean_dan * DAN_TO_N
            f_hat = t_hat - pa
            s, fc, floor = self.p.limits(rec.raw_kpa)
            if faulted:
                st.anchor, st.run_sign, st.run_travel, st.last_pa = None, 0, 0.0, None
            else:
                self._follow(st, f_hat, pa, s, fc)
            if st.anchor is None:
                lo, hi = -s, s
            else:
                u = max(floor, self.p.gain * abs(f_hat - st.anchor))
                lo, hi = max(-s, f_hat - u), min(s, f_hat + u)
                if hi - lo < 2 * floor:           # the estimate sits at or beyond the bound
                    lo, hi = max(-s, min(lo, hi - 2 * floor)), min(s, max(hi, lo + 2 * floor))
            out.append(RopeInterval(t_hat, max(0.0, pa + lo), pa + hi, pa, s, st.anchor is not None))
        self.last = out
        return [r.u for r in out]

    def _follow(self, st: _RopeRun, f_hat: float, pa: float, s: float, fc: float) -> None:
        """The anchor: a saturated estimate the pressure drove there (module doc)."""
        sat = abs(f_hat) >= self.p.saturation * fc and f_hat != 0.0
        sign = (1 if f_hat > 0 else -1) if sat else 0
        if sign == 0:
            st.run_sign, st.run_travel = 0, 0.0
        elif sign != st.run_sign:
            st.run_sign, st.run_travel = sign, 0.0
        elif st.last_pa is not None:
            st.run_travel = max(0.0, st.run_travel + sign * (pa - st.last_pa))
        st.last_pa = pa
        if self.p.anchor and sign != 0 and st.run_travel >= self.p.anchor_travel * s:
            st.anchor = f_hat

    def intervals(self, age_s: float = 0.0) -> list[RopeInterval]:
        """The last frame's intervals, `age_s` after it: widened linearly to the whole physical
        range [pA - S, pA + S] over band_blind_s (no frames: nothing vouched for)."""
        if age_s <= 0:
            return list(self.last)
        k = min(1.0, age_s / self.p.blind_s)
        out = []
        for r in self.last:
            if math.isnan(r.pa):
                out.append(r)
                continue
            lo = r.lo + (max(0.0, r.pa - r.s) - r.lo) * k
            hi = r.hi + (r.pa + r.s - r.hi) * k
            out.append(r._replace(lo=lo, hi=hi, vouched=r.vouched and k < 1.0))
        return out


def deviation_bounds(iv: Sequence[RopeInterval]) -> list[DeviationBand | None]:
    """Each rope's deviation: the node's (over the ropes with a tension) and its exact extremes
    over the intervals of all ropes (module doc). None for a rope with no tension, and for all
    when fewer than two ropes have one, a rope has no interval at all, or they carry nothing."""
    n = len(iv)
    present = [r for r in iv if r.present]
    if len(present) < 2 or any(math.isinf(r.hi) for r in iv):
        return [None] * n
    mean = sum(r.t_hat for r in present) / len(present)
    lo_sum = sum(max(0.0, r.lo) for r in iv)
    hi_sum = sum(r.hi for r in iv)
    if mean <= 0:
        return [None] * n
    out: list[DeviationBand | None] = []
    for r in iv:
        if not r.present:
            out.append(None)
            continue
        a, b = max(0.0, r.lo), r.hi
        dev = r.t_hat / mean - 1.0
        den_max = b + lo_sum - a
        den_min = a + hi_sum - b
        d_max = n * b / den_max - 1.0 if den_max > 0 else math.inf
        d_min = n * a / den_min - 1.0 if den_min > 0 else -1.0
        out.append(DeviationBand(dev, min(d_min, dev), max(d_max, dev)))
    return out


def hidden_reach(band: BandParams, rope_n: float) -> float:
    """The imbalance (a fraction of the mean) the seals' static friction can hide with the ropes
    equal at rope tension `rope_n` (N): the largest deviation any rope's band allows when no seal
    is vouched for, each rope's true tension anywhere in `[T - S, T + S]` at its pressure `T / A`.
    The hoist's standing figure (`ropemon config` prints it at the empty and the rated tension;
    the station shows it at the current mean tension): inside it the pressures and positions
    cannot tell an imbalance. 0.0 for a tension <= 0 (unloaded ropes: no deviation)."""
    if not math.isfinite(rope_n):
        raise ValueError(f"rope_n: {rope_n!r} is not a finite tension")
    if rope_n <= 0:
        return 0.0
    ivs = []
    for area in band.areas_m2:
        s, _fc, _floor = band.limits(rope_n / area / 1000.0)
        ivs.append(RopeInterval(rope_n, max(0.0, rope_n - s), rope_n + s, rope_n, s, False))
    return max((b.reach for b in deviation_bounds(ivs) if b is not None), default=0.0)


def _median(xs: Iterable[float]) -> float:
    v = sorted(xs)
    m = len(v) // 2
    return float(v[m]) if len(v) % 2 else (v[m - 1] + v[m]) / 2.0
