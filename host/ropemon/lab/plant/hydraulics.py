"""Pipe paths of the connection device: along-pipe and local pressure loss, inertance.

A path is the pipe from one cylinder's cavity to a point downstream (its sensor
tap, or the connecting assembly): straight segments and fittings. Losses are
vectorised over ropes and (for outputs) over time:

- along-pipe: Darcy-Weisbach, lambda = max(64/Re, 0.3164 Re^-0.25) (laminar, then
  Blasius; the max is continuous, so the Jacobian is too);
- local: the 2-K form K = K1/Re + Kinf, i.e. dp = K1 mu v / (2 d) + Kinf rho v|v|/2,
  with K1, Kinf taken once from Hooper's tables in `fluids` (laminar hose flow makes
  the K1 term dominate); contractions and expansions use fluids' turbulent K.

This is the simulator's own pipe-loss model, kept apart from the product's
(ropemon.commission.losses, which computes the node's loss table) on purpose and with other
correlations: the plant is the truth the node's model is tested against.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ropemon.commission.losses import _HOOPER_BENDS, _HOOPER_TEES, _HOOPER_VALVES, INCH_M


def _area(d):
    return math.pi * d * d / 4


def fitting_K1_Kinf(f) -> tuple[float, float]:
    """(K1, Kinf) of a site Fitting, referred to the velocity in f.bore_m."""
    import fluids.fittings as ft

    if f.kind == "custom":
        return 0.0, f.K
    if f.kind == "contraction":
        return 0.0, ft.contraction_sharp(f.from_bore_m, f.bore_m)
    if f.kind == "expansion":
        return 0.0, ft.diffuser_sharp(f.from_bore_m, f.bore_m) * (f.bore_m / f.from_bore_m) ** 4
    name = {"bend": lambda: _HOOPER_BENDS[(f.angle_deg, f.style)], "tee": lambda: _HOOPER_TEES[f.flow],
            "valve": lambda: _HOOPER_VALVES[f.valve]}[f.kind]()
    kinf = ft.Hooper2K(Di=f.bore_m / INCH_M, Re=1e300, name=name)
    k1 = ft.Hooper2K(Di=f.bore_m / INCH_M, Re=1.0, name=name) - kinf
    return k1, kinf


@dataclass(frozen=True)
class Segment:
    length_m: float
    bore_m: float


@dataclass(frozen=True)
class Local:
    bore_m: float
    K1: float
    Kinf: float


@dataclass(frozen=True)
class Path:
    segments: tuple[Segment, ...]
    locals: tuple[Local, ...] = ()

    def inertance(self, rho: float) -> float:
        """rho * sum(L / area) (Pa s^2 / m^3)."""
        return rho * sum(s.length_m / _area(s.bore_m) for s in self.segments)

    def volume_m3(self) -> float:
        return sum(s.length_m * _area(s.bore_m) for s in self.segments)

    @classmethod
    def from_site_pipe(cls, pipe, extra: "Path | None" = None) -> "Path":
        segs = tuple(Segment(s.length_m, s.bore_m) for s in pipe.segments)
        locs = tuple(Local(f.bore_m, *fitting_K1_Kinf(f)) for f in pipe.fittings)
        if extra is not None:
            segs += extra.segments
            locs += extra.locals
        return cls(segs, locs)

    def then(self, other: "Path") -> "Path":
        return Path(self.segments + other.segments, self.locals + other.locals)


class PathSet:
    """One Path per rope, evaluated together: dp(q) and d(dp)/dq for flows q[..., N]."""

    def __init__(self, paths: list[Path]):
        self.n = len(paths)
        si, sl, sd, li, ld, k1, ki = [], [], [], [], [], [], []
        for i, p in enumerate(paths):
            for s in p.segments:
                si.append(i), sl.append(s.length_m), sd.append(s.bore_m)
            for c in p.locals:
                li.append(i), ld.append(c.bore_m), k1.append(c.K1), ki.append(c.Kinf)
        self.s_idx = np.array(si, dtype=int)
        self.s_L = np.array(sl)
        self.s_d = np.array(sd)
        self.s_a = math.pi * self.s_d ** 2 / 4
        self.l_idx = np.array(li, dtype=int)
        self.l_d = np.array(ld)
        self.l_a = math.pi * self.l_d ** 2 / 4
        self.l_K1 = np.array(k1)
        self.l_Kinf = np.array(ki)
        # sum over segments/fittings of each rope by one matrix product
        self.s_sum = np.zeros((len(si), self.n))
        self.s_sum[np.arange(len(si)), self.s_idx] = 1.0
        self.l_sum = np.zeros((len(li), self.n))
        self.l_sum[np.arange(len(li)), self.l_idx] = 1.0
        # the K1 term of the fittings is linear in q (per unit viscosity), the Kinf term quadratic
        self.lin_loc = (self.l_K1 / (2.0 * self.l_d * self.l_a)) @ self.l_sum if len(li) else np.zeros(self.n)
        self.quad_per_rho = (self.l_Kinf / (2.0 * self.l_a ** 2)) @ self.l_sum if len(li) else np.zeros(self.n)
        self.inertance_per_rho = (self.s_L / self.s_a) @ self.s_sum

    def dp(self, q, rho, mu):
        """Pressure loss (Pa, sign of q) and its derivative d dp/dq, for q[..., N]; rho, mu broadcast."""
        rho = np.asarray(rho)[..., None] if np.ndim(rho) else rho
        mu = np.asarray(mu)[..., None] if np.ndim(mu) else mu
        v = q[..., self.s_idx] / self.s_a
        av = np.abs(v)
        # along-pipe: the larger of laminar and Blasius (they meet at Re ~ 1190)
        lam = 32.0 * mu * self.s_L / self.s_d ** 2 * v
        re = rho * av * self.s_d / mu
        bla = 0.3164 * np.power(np.maximum(re, 1e-12), -0.25) * self.s_L / self.s_d * rho * v * av / 2.0
        turb = np.abs(bla) > np.abs(lam)
        seg = np.where(turb, bla, lam)
        dseg = np.where(turb, 1.75 * np.abs(bla) / np.maximum(av, 1e-300), 32.0 * mu * self.s_L / self.s_d ** 2) / self.s_a
        quad = self.quad_per_rho * rho
        aq = np.abs(q)
        dp = seg @ self.s_sum + (mu * self.lin_loc) * q + quad * q * aq
        # derivative: segments belong to one rope each, so d/dq_i is the per-rope sum
        ddp = dseg @ self.s_sum + mu * self.lin_loc + 2.0 * quad * aq
        return dp, ddp
