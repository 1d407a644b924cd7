"""Step convergence check: run a scenario at its step and at half of it, compare the truth arrays
(rope tensions and the friction/pressure split the node estimates), and check that each run's
piston positions agree with the integral of its recorded velocities."""
from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from ropemon.lab.plant.run import simulate
from ropemon.lab.plant.scenario import build

# truth array -> (scale to the reported unit, unit)
COMPARED = {"tension_N": (1.0, "N"), "friction_N": (1.0, "N"), "piston_x_m": (1e6, "um"),
            "piston_v_m_s": (1e6, "um_s"), "p_tap_Pa": (1e-3, "kPa")}


def x_minus_integral_of_v(t: np.ndarray, x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """x(t) - x(0) - (trapezoidal integral of v from 0 to t) per sample and rope (m)."""
    iv = np.concatenate([np.zeros((1, x.shape[1])),
                         np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t)[:, None], axis=0)])
    return (x - x[0]) - iv


def halved_doc(doc: dict, sc, factor: float = 2.0) -> dict:
    """The scenario document with every step (base, max, bounce phase per step) divided by factor."""
    d = dict(doc)
    d["step_s"] = sc.step_s / factor
    d["max_step_s"] = sc.max_step_s / factor
    d["bounce_rad_per_step"] = sc.bounce_rad_per_step / factor
    return d


def halving_difference(path: Path | str, doc_overrides: dict | None = None) -> dict:
    """Largest differences between the scenario's step plan and one with every step halved, at the
    common sample times: `max_d<array>` in the units of COMPARED (e.g. max_dfriction_N_N), with the
    time of the largest (`at_<array>_s`); and each run's largest |x - x0 - integral of v| (um)."""
    path = Path(path)
    with path.open("rb") as f:
        doc = tomllib.load(f)
    doc.update(doc_overrides or {})
    full = build(doc, path)
    half = build(halved_doc(doc, full), path)
    a, b = simulate(full), simulate(half)
    n = min(len(a.t), len(b.t))
    out: dict[str, Any] = {"rated_N": full.rated_rope_tension_N, "method": full.method, "steps": len(full.steps),
           "steps_half": len(half.steps), "wall_s": a.wall_s, "wall_half_s": b.wall_s,
           "tension_range_N": float(np.ptp(a.truth["tension_N"])),
           "friction_range_N": float(np.ptp(a.truth["friction_N"]))}
    for key, (scale, unit) in COMPARED.items():
        d = np.abs(a.truth[key][:n] - b.truth[key][:n]) * scale
        out[f"max_d{key}_{unit}"] = float(d.max())
        out[f"at_{key}_s"] = float(a.t[int(d.max(axis=1).argmax())])
    out["max_dT_N"] = out["max_dtension_N_N"]
    out["at_s"] = out["at_tension_N_s"]
    out["max_dT_pct_rated"] = 100.0 * out["max_dT_N"] / full.rated_rope_tension_N
    out["max_dF_pct_rated"] = 100.0 * out["max_dfriction_N_N"] / full.rated_rope_tension_N
    for tag, r in (("", a), ("_half", b)):
        c = np.abs(x_minus_integral_of_v(r.t, r.truth["piston_x_m"], r.truth["piston_v_m_s"]))
        out[f"x_vs_int_v_um{tag}"] = float(c.max() * 1e6)
    return out
