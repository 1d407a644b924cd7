"""The piston seal's friction in floating point: the LuGre model of docs/model.md ("LuGre seal friction").

- The pressure lines: Fs, Fc, vs and sigma2 each `X(p) = intercept + slope p`, p in MPa
  (`LINES`; `line_at`, `lines_at`, `lines`). A line is evaluated by the station's `Line`
  (ropemon.station.uncertainty), which needs Fs and Fc for its band and may import no
  commissioning module.
- The Stribeck curve `g(v) = Fc + (Fs - Fc) exp(-(v/vs)^2)` and the steady sliding force
  `sgn(v) g(v) + sigma2 v` (`g`, `steady_force`).
- The LuGre state's exact update for a velocity held over a step h, stable at any step
  (explicit Euler is not at these stiffnesses):
  `z <- z_ss + (z - z_ss) exp(-sigma0 |v| h / g(v))`, `z_ss = sgn(v) g(v) / sigma0`;
  `F = sigma0 z + sigma1 dz/dt + sigma2 v`. Sample by sample in plain floats (`LuGre`), or
  in w = sigma0 z over arrays of steady forces and decays (`bristle_force`).

`line_at`, `lines_at`, `g` and `steady_force` take floats (math) or numpy arrays (numpy).
Used by ropemon.commission.calibrate (the fit), ropemon.commission.reference (whose
noise-robust observer is the node's own discrete form) and the lab's test bed and
estimators. The simulator's seal laws (ropemon.lab.plant) are written apart on purpose:
they are the truth this model is tested against.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ropemon.station.uncertainty import Line

LINES = ("Fs", "Fc", "vs", "sigma2")   # the friction parameters linear in pressure


def lines(fr: dict[str, Any]) -> tuple[Line, Line, Line, Line]:
    """The lines Fs, Fc, vs, sigma2 of a friction section (each {"intercept", "slope"})."""
    fs, fc, vs, s2 = (Line(fr[key]["intercept"], fr[key]["slope"]) for key in LINES)
    return fs, fc, vs, s2


def line_at(fr: dict[str, Any], key: str, p_mpa: Any) -> Any:
    """The line `fr[key]` ({"intercept", "slope"}) at pressure p (MPa)."""
    d = fr[key]
    return Line(d["intercept"], d["slope"]).at(p_mpa)


def lines_at(fr: dict[str, Any], p_mpa: Any) -> tuple[Any, Any, Any, Any]:
    """(Fs, Fc, vs, sigma2) of the friction section `fr` at pressure p (MPa)."""
    fs, fc, vs, s2 = lines(fr)
    return fs.at(p_mpa), fc.at(p_mpa), vs.at(p_mpa), s2.at(p_mpa)


def g(v: Any, fs: Any, fc: Any, vs: Any) -> Any:
    """The Stribeck curve Fc + (Fs - Fc) exp(-(v/vs)^2) (N; v and vs in m/s)."""
    u = v / vs
    if type(u) is float:
        return fc + (fs - fc) * math.exp(-u ** 2)
    return fc + (fs - fc) * np.exp(-u ** 2)


def steady_force(v: Any, fs: Any, fc: Any, vs: Any, sigma2: Any) -> Any:
    """LuGre's force in steady sliding at v: sgn(v) g(v) + sigma2 v (0 at v = 0)."""
    gv = g(v, fs, fc, vs)
    if type(gv) is float:
        return math.copysign(gv, v) + sigma2 * v if v else 0.0
    return np.sign(v) * gv + sigma2 * v


class LuGre:
    """LuGre seal friction from a friction section (`LINES` as lines, sigma0, sigma1), one
    step at a time in plain floats: `force(v, p, h)` advances z by h at velocity v (m/s) and
    pressure p (MPa) with the exact update (h = 0: no step) and returns F (N). z starts at 0
    (unloaded); dz/dt is taken at the end of the step. `fr` is read when the law is made."""

    def __init__(self, fr: dict[str, Any]):
        self.lines = lines(fr)
        self.sigma0, self.sigma1 = fr["sigma0"], fr["sigma1"]
        self.z = 0.0
        self._p: Any = None
        self._at: tuple[Any, Any, Any, Any] = (0.0, 0.0, 0.0, 0.0)

    def force(self, v: float, p: float, h: float) -> float:
        if p != self._p:   # the lines' values are kept while the pressure stays (a bed holds it)
            fs_l, fc_l, vs_l, s2_l = self.lines
            self._p, self._at = p, (fs_l.at(p), fc_l.at(p), vs_l.at(p), s2_l.at(p))
        fs, fc, vs, s2 = self._at
        s0 = self.sigma0
        gv = g(v, fs, fc, vs)
        if v:
            z_ss = math.copysign(gv / s0, v)
            self.z = z_ss + (self.z - z_ss) * math.exp(-s0 * abs(v) / gv * h)
        dz = v - s0 * abs(v) * self.z / gv
        return s0 * self.z + self.sigma1 * dz + s2 * v


def bristle_force(w_ss: np.ndarray, decay: np.ndarray, w0: float) -> np.ndarray:
    """w = sigma0 z over the steps by the exact update with v held over each step.

    w_ss = sgn(v) g(v) is the steady bristle force and decay = exp(-sigma0 |v| h / g(v))
    per step; w+ = w_ss + (w - w_ss) decay from w0, each step's w returned.
    """
    out = np.empty(len(w_ss))
    w = w0
    for i, (ws, d) in enumerate(zip(w_ss.tolist(), decay.tolist())):
        w = ws + (w - ws) * d
        out[i] = w
    return out
