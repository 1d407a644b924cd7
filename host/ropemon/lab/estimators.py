"""The rope-tension estimators compared in `ropemon evaluate`, simplest first.

All follow docs/model.md, T_i = (p_tap,i + dp_i(Q_i)) A_i + F_i, and differ in
the seal-friction term F_i and in whether the pipe loss dp_i is compensated:

    raw              F = 0, dp = 0 (the uncompensated p*A reading)
    coulomb          F = Fc(p) sgn(v)
    coulomb-viscous  F = Fc(p) sgn(v) + sigma2(p) v
    stribeck         F = g(v) sgn(v) + sigma2(p) v, g as in LuGre (its steady state)
    lugre-const      LuGre with every parameter frozen at one calibration pressure
    lugre-p          LuGre with Fs, Fc, vs, sigma2 linear in pressure (the node's model)

each also as `NAME+loss` with dp compensated. The static laws are evaluated here
(with the pressure lines and g of `ropemon.commission.seal`) on the sensor signals
(pressure at the tap, piston velocity, pipe loss) that the float reference derives;
the LuGre ones are the float reference itself (`ropemon.commission.reference`) run on
a modified `physical` section (`lugre_const_physical`, `no_loss_physical`), so LuGre
is written once, in the reference.

The static laws have no memory: at rest (v = 0) they predict no friction, while
a real seal holds the piston; that is the effect the paper's field test shows.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ropemon.commission.seal import LINES, g, line_at, lines_at

STATIC_FRICTION_LAWS = ("raw", "coulomb", "coulomb-viscous", "stribeck")
LUGRE_LAWS = ("lugre-const", "lugre-p")
FRICTION_LAWS = STATIC_FRICTION_LAWS + LUGRE_LAWS
ESTIMATORS = tuple(n + s for n in FRICTION_LAWS for s in ("", "+loss"))
FULL_COMPENSATION = "lugre-p+loss"  # what the node runs

PRESSURE_DEPENDENT = LINES

# Below a dead band the sign of the velocity estimate is noise: a static law reads
# no friction there (Karnopp-style, as such estimators are used in practice;
# without it sensor noise at rest flips +-Fc every sample). The evaluation sets it
# from the velocity noise at standstill (`deadband_from_standstill`); this is the least.
VELOCITY_DEADBAND_M_S = 1e-4
DEADBAND_SIGMAS = 3.0


def deadband_from_standstill(v_m_s: np.ndarray) -> float:
    """Dead band for the static laws: DEADBAND_SIGMAS x the RMS velocity estimate while
    the hoist stands still (what a site can record before commissioning)."""
    v = np.asarray(v_m_s, float)
    v = v[np.isfinite(v)]
    rms = float(np.sqrt(np.mean(v * v))) if v.size else 0.0
    return max(VELOCITY_DEADBAND_M_S, DEADBAND_SIGMAS * rms)


@dataclass
class Signals:
    """Per-sample inputs of an estimator, SI, arrays of shape (samples, ropes)."""

    p_tap_pa: np.ndarray   # pressure at the sensor tap
    v_m_s: np.ndarray      # piston velocity estimate (positive: pulled out)
    dp_pa: np.ndarray      # pipe loss cavity -> tap the node's table gives for its flow


def static_friction_n(law: str, friction: dict, p_tap_pa: np.ndarray, v_m_s: np.ndarray,
                      deadband_m_s: float = VELOCITY_DEADBAND_M_S) -> np.ndarray:
    """Seal friction force (N, sign of v) of a memoryless law at each sample."""
    p_mpa = np.asarray(p_tap_pa, float) * 1e-6
    v = np.asarray(v_m_s, float)
    sgn = np.where(np.abs(v) > deadband_m_s, np.sign(v), 0.0)
    if law == "raw":
        return np.zeros_like(v)
    fs, fc, vs, s2 = lines_at(friction, p_mpa)
    if law == "coulomb":
        return fc * sgn
    if law == "coulomb-viscous":
        return fc * sgn + s2 * v
    if law == "stribeck":
        return g(v, fs, fc, vs) * sgn + s2 * v
    raise ValueError(f"unknown static friction law {law!r}; known: {STATIC_FRICTION_LAWS}")


def static_estimate_n(name: str, physical: dict, sig: Signals,
                      deadband_m_s: float = VELOCITY_DEADBAND_M_S) -> np.ndarray:
    """Rope tensions (N, shape (samples, ropes)) of a static estimator `LAW` or `LAW+loss`."""
    law, _, loss = name.partition("+")
    if loss not in ("", "loss"):
        raise ValueError(f"unknown estimator {name!r}; known: {ESTIMATORS}")
    area = np.asarray(physical["cylinder_area_m2"], float)
    p_cav = sig.p_tap_pa + (sig.dp_pa if loss else 0.0)
    return p_cav * area + static_friction_n(law, physical["friction"], sig.p_tap_pa, sig.v_m_s, deadband_m_s)


def lugre_const_physical(physical: dict, calibration_pressure_mpa: float) -> dict:
    """`physical` with Fs, Fc, vs, sigma2 frozen at their values at one pressure (slopes zeroed)."""
    out = copy.deepcopy(physical)
    for name in PRESSURE_DEPENDENT:
        line = out["friction"][name]
        line["intercept"], line["slope"] = line_at(out["friction"], name, calibration_pressure_mpa), 0.0
    return out


def no_loss_physical(physical: dict) -> dict:
    """`physical` with a pipe-loss table of zeros: the compensation without the loss term."""
    out = copy.deepcopy(physical)
    out["loss"]["dp_Pa"] = np.zeros_like(np.asarray(out["loss"]["dp_Pa"], float)).tolist()
    return out
