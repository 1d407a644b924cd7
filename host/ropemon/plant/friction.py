"""Seal friction laws of the pistons, pluggable: LuGre (default) and a Coulomb-Stribeck law.

Each law gives, vectorised over ropes, the friction force F (sign of the sliding
velocity v, docs/model.md), the rate of its internal state z, and the partial
derivatives the implicit solver needs. Pressures enter in MPa (cavity pressure,
clamped at 0: cavitation is not modelled). Parameters may be per rope.

- `LuGre`: Canudas de Wit et al. 1995 with Fs, Fc, vs, sigma2 linear in pressure,
  the form the node compensates.
- `CoulombStribeck`: a static law like Simscape's cylinder friction,
  F = (Fc + (Fs - Fc) exp(-(v/vs)^2)) tanh(v/v_th) + sigma2 v, with the same
  pressure lines; it has no presliding state, so the node's LuGre compensation
  meets a plant it does not share a model with.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

LINE_KEYS = ("Fs", "Fc", "vs", "sigma2")


@dataclass(frozen=True)
class Line:
    """X(p) = intercept + slope * p_MPa."""

    intercept: float
    slope: float = 0.0

    def at(self, p_mpa):
        return self.intercept + self.slope * p_mpa


@dataclass
class FrictionOut:
    F: np.ndarray
    zdot: np.ndarray
    F_v: np.ndarray
    F_z: np.ndarray
    F_p: np.ndarray      # per Pa
    zd_v: np.ndarray
    zd_z: np.ndarray
    zd_p: np.ndarray     # per Pa


def _g(v, p_mpa, Fs: Line, Fc: Line, vs: Line):
    """Stribeck curve g(v, p) and its partials dg/dv, dg/dp (per MPa)."""
    fs, fc, vss = Fs.at(p_mpa), Fc.at(p_mpa), vs.at(p_mpa)
    e = np.exp(-(v / vss) ** 2)
    g = fc + (fs - fc) * e
    g_v = (fs - fc) * e * (-2.0 * v / (vss * vss))
    g_p = Fc.slope + (Fs.slope - Fc.slope) * e + (fs - fc) * e * (2.0 * v * v / vss ** 3) * vs.slope
    return g, g_v, g_p


@dataclass(frozen=True)
class LuGre:
    Fs: Line
    Fc: Line
    vs: Line
    sigma2: Line
    sigma0: float
    sigma1: float
    name: str = field(default="lugre", init=False)

    def evaluate(self, v, z, p_Pa) -> FrictionOut:
        pos = p_Pa > 0.0
        p = np.where(pos, p_Pa, 0.0) * 1e-6
        dpos = np.where(pos, 1e-6, 0.0)
        g, g_v, g_p = _g(v, p, self.Fs, self.Fc, self.vs)
        av = np.abs(v)
        s0 = self.sigma0
        zdot = v - s0 * av * z / g
        zd_v = 1.0 - s0 * z * (np.sign(v) * g - av * g_v) / (g * g)
        zd_z = -s0 * av / g
        zd_p = s0 * av * z * g_p / (g * g) * dpos
        s2 = self.sigma2.at(p)
        F = s0 * z + self.sigma1 * zdot + s2 * v
        return FrictionOut(F, zdot, self.sigma1 * zd_v + s2, s0 + self.sigma1 * zd_z,
                           self.sigma1 * zd_p + self.sigma2.slope * v * dpos, zd_v, zd_z, zd_p)

    def as_fit(self) -> dict:
        """The parameters in the form of `ropemon fit-friction` output (docs/config.md `friction`)."""
        d = {k: {"slope": getattr(self, k).slope, "intercept": getattr(self, k).intercept} for k in LINE_KEYS}
        d["sigma0"] = self.sigma0
        d["sigma1"] = self.sigma1
        return d


@dataclass(frozen=True)
class CoulombStribeck:
    Fs: Line
    Fc: Line
    vs: Line
    sigma2: Line
    v_threshold: float
    name: str = field(default="coulomb-stribeck", init=False)

    def evaluate(self, v, z, p_Pa) -> FrictionOut:
        pos = p_Pa > 0.0
        p = np.where(pos, p_Pa, 0.0) * 1e-6
        dpos = np.where(pos, 1e-6, 0.0)
        g, g_v, g_p = _g(v, p, self.Fs, self.Fc, self.vs)
        th = np.tanh(v / self.v_threshold)
        s2 = self.sigma2.at(p)
        F = g * th + s2 * v
        F_v = g_v * th + g * (1.0 - th * th) / self.v_threshold + s2
        F_p = (g_p * th + self.sigma2.slope * v) * dpos
        zero = np.zeros_like(F)
        # z is unused: it relaxes to 0 so the state vector keeps one shape for every law.
        return FrictionOut(F, -z, F_v, zero, F_p, zero, zero - 1.0, zero)


def from_table(t: dict, where: str) -> LuGre | CoulombStribeck:
    """Build a law from a scenario's [plant.friction] table; errors name the field."""
    from ropemon.plant.scenario import ScenarioError, number

    law = t.get("law", "lugre")
    lines = {}
    for k in LINE_KEYS:
        v = t.get(k)
        if not isinstance(v, dict):
            raise ScenarioError(f"{where}.{k}: missing, or not a table {{intercept = ..., slope = ...}}")
        unknown = set(v) - {"intercept", "slope"}
        if unknown:
            raise ScenarioError(f"{where}.{k}.{sorted(unknown)[0]}: unknown field")
        lines[k] = Line(number(v, "intercept", f"{where}.{k}"), number(v, "slope", f"{where}.{k}", default=0.0))
    if lines["vs"].intercept <= 0:
        raise ScenarioError(f"{where}.vs.intercept: must be > 0")
    if law == "lugre":
        extra = {"law", *LINE_KEYS, "sigma0", "sigma1"}
        f = LuGre(**lines, sigma0=number(t, "sigma0", where, gt=0), sigma1=number(t, "sigma1", where, ge=0))
    elif law == "coulomb-stribeck":
        extra = {"law", *LINE_KEYS, "v_threshold"}
        f = CoulombStribeck(**lines, v_threshold=number(t, "v_threshold", where, gt=0))
    else:
        raise ScenarioError(f"{where}.law: must be 'lugre' or 'coulomb-stribeck', got {law!r}")
    unknown = set(t) - extra
    if unknown:
        raise ScenarioError(f"{where}.{sorted(unknown)[0]}: unknown field for law {law!r}")
    return f
