"""Step convergence check: run a scenario at its step and at half of it, compare rope tensions."""
from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from ropemon.plant.run import simulate
from ropemon.plant.scenario import build


def halving_difference(path: Path | str) -> dict:
    """Largest rope-tension difference (N) between the scenario's step plan and one with every step
    halved (base step, max step and bounce phase per step all / 2), at the common sample times."""
    path = Path(path)
    with path.open("rb") as f:
        doc = tomllib.load(f)
    full = build(doc, path)
    half_doc = dict(doc)
    half_doc["step_s"] = full.step_s / 2
    half_doc["max_step_s"] = float(doc.get("max_step_s", full.max_step_s)) / 2
    half_doc["bounce_rad_per_step"] = float(doc.get("bounce_rad_per_step", full.bounce_rad_per_step)) / 2
    half = build(half_doc, path)
    a, b = simulate(full), simulate(half)
    n = min(len(a.t), len(b.t))
    dT = np.abs(a.truth["tension_N"][:n] - b.truth["tension_N"][:n])
    k = int(dT.max(axis=1).argmax())
    return {"max_dT_N": float(dT.max()), "at_s": float(a.t[k]), "rated_N": full.rated_rope_tension_N,
            "max_dT_pct_rated": 100.0 * float(dT.max()) / full.rated_rope_tension_N,
            "tension_range_N": float(np.ptp(a.truth["tension_N"])), "steps": len(full.steps),
            "steps_half": len(half.steps), "wall_s": a.wall_s, "wall_half_s": b.wall_s}
