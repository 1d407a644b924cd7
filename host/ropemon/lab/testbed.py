"""A simulated friction test bed: the CSV `ropemon fit-friction` reads, from known seal friction.

It plays the test procedure of docs/commissioning.md on a cylinder whose seal
friction is known (LuGre with Fs, Fc, vs, sigma2 linear in pressure: the product's float
model, ropemon.commission.seal; any ropemon.lab.plant law of a scenario's [plant.friction];
or any object with `force(v_m_s, p_MPa, h_s) -> N`),
and records what the real bed's instruments would: time, oil pressure, piston velocity
and friction force, each with measurement noise. Used by the tests, the docs, the example fit
scenarios/paper-friction.json and the accuracy evaluation.

    python -m ropemon.lab.testbed --out bed.csv [--seed N] [--no-presliding]
    python -m ropemon.lab.testbed --scenario scenarios/paper-field-trip.toml --out bed.csv

With --scenario the bed runs that scenario's hidden seal ([plant.friction], read
by ropemon.lab.plant, any law; --rope N picks rope N's seal when the table has a per-rope
force_scale), so a site's fit describes the seal its plant actually has.
"""
from __future__ import annotations

import argparse
import csv
import math
import random
import sys
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from ropemon.commission.seal import LuGre, lines_at, steady_force
from ropemon.commission.seal import line_at as line

# Seal friction of the example site's 100 mm cylinders (lip seal, ISO VG46), the
# truth behind scenarios/paper-friction.json. Magnitudes: the paper's field
# hoist read 17 % low at rest (~8 kN per rope held by the seals at ~6 MPa).
PAPER_SEAL = {
    "Fs": {"slope": 1000.0, "intercept": 2000.0},      # N/MPa, N
    "Fc": {"slope": 600.0, "intercept": 1200.0},       # N/MPa, N
    "vs": {"slope": -0.0003, "intercept": 0.012},      # m/s/MPa, m/s (falls with pressure, as in the paper)
    "sigma2": {"slope": 3000.0, "intercept": 20000.0},  # N s/m/MPa, N s/m
    "sigma0": 5.0e7,                                    # N/m: ~0.1 mm pre-sliding displacement
    "sigma1": 8.0e4,                                    # N s/m
}

PRESSURES_MPA = (2.0, 4.0, 6.0, 8.0, 10.0, 12.0)
SPEEDS_M_S = (0.0005, 0.001, 0.002, 0.003, 0.005, 0.007, 0.010, 0.015, 0.020, 0.030, 0.045, 0.060)


@dataclass(frozen=True)
class Noise:
    """Instrument noise (one standard deviation) of the bed's recordings."""
    friction_N: float = 30.0          # force sensor, absolute
    friction_frac: float = 0.005      # and relative to the reading
    velocity_m_s: float = 2e-5        # differentiated displacement sensor
    velocity_frac: float = 0.01
    pressure_MPa: float = 0.02


class FrictionLaw(Protocol):
    def force(self, v_m_s: float, p_MPa: float, h_s: float) -> float:
        """Advance the law's state by h_s (0: do not advance) at velocity v and pressure p; return the force (N)."""


def stribeck_N(params: dict[str, Any], v_m_s: float, p_MPa: float) -> float:
    """Steady-state LuGre friction at constant velocity (the curve fit-friction fits)."""
    return steady_force(v_m_s, *lines_at(params, p_MPa))


class PlantLaw:
    """A ropemon.lab.plant friction law as a bed law. Laws with pre-sliding states (Maxwell-slip,
    elasto-plastic: `implicit_step`) advance them by implicit Euler over each step, starting
    unloaded; a law without (coulomb-stribeck) is evaluated as it is."""

    def __init__(self, law: Any):
        self.law = law
        self.stateful = hasattr(law, "implicit_step")
        self.z: Any = [0.0] * law.n_z if law.n_z > 1 else 0.0

    def force(self, v: float, p: float, h: float) -> float:
        if not self.stateful:
            out = self.law.evaluate(np.array([v]), np.zeros(1), np.array([p * 1e6]))
            return float(out.F[0])
        pm = max(p, 0.0)
        if h:
            self.z = self.law.implicit_step(v, self.z, pm, h)
        return float(self.law.terms(v, self.z, pm, 0.0, False)[0])


def scenario_seal(path: Path | str, rope: int | None = None) -> tuple[dict[str, Any] | None, Any]:
    """(params, law_factory) for `run` from a scenario's hidden [plant.friction] table, of any law.

    A LuGre seal gives its parameters (law_factory None: the bed's own LuGre); any
    other law is wrapped as it is (params None: no lines to scatter about). With a
    per-rope `force_scale`, `rope` picks that rope's seal; None is the seal at scale 1.
    """
    from ropemon.station import tomlfields
    from ropemon.lab.plant import friction as plant_friction
    from ropemon.lab.plant.scenario import ScenarioError, table

    doc = tomlfields.load(path, ScenarioError)
    law = plant_friction.from_table(table(table(doc, "plant", ""), "friction", "plant"),
                                    "plant.friction")
    if rope is not None and law.force_scale is not None and not 0 <= rope < len(law.force_scale):
        raise ScenarioError(f"plant.friction.force_scale: no rope {rope} (it has {len(law.force_scale)})")
    seal = law.rope_seal(rope)
    if isinstance(seal, plant_friction.LuGre):
        return seal.as_fit(), None
    return None, lambda _level: PlantLaw(seal)


def velocity_profile(speeds: tuple[float, ...], hold_s: float, ramp_s: float, dt: float,
                     min_travel_m: float = 2e-3) -> np.ndarray:
    """Constant-velocity runs at every speed, each forward then back, joined by linear ramps.

    Each speed is held for hold_s, longer at slow speeds so every run travels at
    least min_travel_m (the bristles settle within a fraction of a millimetre).
    """
    targets = [s * d for s in speeds for d in (1.0, -1.0)]
    parts, v_prev = [], 0.0
    for v in targets + [0.0]:
        n_ramp = max(1, round(ramp_s / dt))
        parts.append(np.linspace(v_prev, v, n_ramp, endpoint=False))
        if v:
            parts.append(np.full(max(1, round(max(hold_s, min_travel_m / abs(v)) / dt)), v))
        v_prev = v
    parts.append(np.zeros(round(0.5 / dt)))
    return np.concatenate(parts)


def presliding_profile(amplitude_m: float, period_s: float, cycles: int, dt: float) -> np.ndarray:
    """Slow sinusoidal reversals x = A sin(w t): the piston stays (mostly) in pre-sliding."""
    t = np.arange(round(cycles * period_s / dt)) * dt
    w = 2 * math.pi / period_s
    return np.concatenate([amplitude_m * w * np.cos(w * t), np.zeros(round(0.5 / dt))])


def presliding_period_s(params: dict[str, Any] | None, amplitude_m: float = 4e-4,
                        pressures_MPa: tuple[float, ...] = PRESSURES_MPA) -> float:
    """The reversal period that keeps the peak speed below vs/8 at every bed pressure
    (fit-friction takes only |v| < vs/4 as pre-sliding), at least the default 4 s."""
    if params is None:
        return 4.0
    vs_min = min(line(params, "vs", p) for p in pressures_MPa)
    return max(4.0, 2 * math.pi * amplitude_m / (vs_min / 8))


def run(params: dict[str, Any] | None = None, *, pressures_MPa: tuple[float, ...] = PRESSURES_MPA,
        speeds_m_s: tuple[float, ...] = SPEEDS_M_S, hold_s: float = 2.5, ramp_s: float = 0.2,
        sample_hz: int = 100, presliding: bool = True, presliding_amplitude_m: float = 4e-4,
        presliding_period_s: float = 4.0, presliding_cycles: int = 4, noise: Noise = Noise(), seed: int = 0,
        seal_scatter: float = 0.0,
        law_factory: Callable[[dict[str, Any]], FrictionLaw] | None = None) -> dict[str, np.ndarray]:
    """Play the test procedure; return the recorded columns (and the noiseless truth).

    At each pressure level: constant-velocity runs in both directions at every
    speed, then (when `presliding`) slow reversals. `law_factory(params)` makes a
    fresh friction law per pressure level (default: LuGre). `seal_scatter` > 0
    moves each level's Fs, Fc, vs, sigma2 off their lines by that relative
    standard deviation, as a real seal is not exactly linear in pressure.
    """
    make = law_factory or LuGre
    params = PAPER_SEAL if params is None and law_factory is None else params
    if seal_scatter and params is None:
        raise ValueError("seal_scatter needs a seal with pressure lines (params)")
    rng = random.Random(seed)
    dt = 1.0 / sample_hz
    substeps = 16  # the law runs finer than the recorder samples (and than the fitter's model)
    h = dt / substeps
    prof = velocity_profile(speeds_m_s, hold_s, ramp_s, dt)
    if presliding:
        prof = np.concatenate([prof, presliding_profile(presliding_amplitude_m, presliding_period_s,
                                                        presliding_cycles, dt)])
    cols: dict[str, list[float]] = {k: [] for k in ("time_s", "pressure_MPa", "velocity_m_s", "friction_N",
                                                     "true_velocity_m_s", "true_friction_N")}
    t = 0.0
    for p in pressures_MPa:
        level = params
        if seal_scatter:
            level = dict(params)
            for key in ("Fs", "Fc", "vs", "sigma2"):
                value = line(params, key, p) * (1.0 + rng.gauss(0.0, seal_scatter))
                level[key] = {"slope": 0.0, "intercept": value}
        law = make(level)
        v_prev = 0.0
        for v in prof:
            v = float(v)
            f = 0.0
            for k in range(substeps):
                # velocity interpolated within the sample (mid-substep) so ramps and sinusoids are smooth
                law.force(v_prev + (v - v_prev) * (k + 0.5) / substeps, p, h)
            f = law.force(v, p, 0.0)  # the force at the sampling instant
            v_prev = v
            cols["time_s"].append(t)
            cols["pressure_MPa"].append(p + rng.gauss(0.0, noise.pressure_MPa))
            cols["velocity_m_s"].append(v + rng.gauss(0.0, noise.velocity_m_s + noise.velocity_frac * abs(v)))
            cols["friction_N"].append(f + rng.gauss(0.0, noise.friction_N + noise.friction_frac * abs(f)))
            cols["true_velocity_m_s"].append(v)
            cols["true_friction_N"].append(f)
            t += dt
        t += 5.0  # the bed is re-pressurised between levels: a gap in time
    return {k: np.asarray(v) for k, v in cols.items()}


CSV_COLUMNS = ("time_s", "pressure_MPa", "velocity_m_s", "friction_N")


def write_csv(path: Path | str, data: dict[str, np.ndarray], truth_columns: bool = False) -> None:
    """Write the bed's record in the fit-friction format (docs/commissioning.md)."""
    cols = list(CSV_COLUMNS) + (["true_velocity_m_s", "true_friction_N"] if truth_columns else [])
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for row in zip(*(data[c] for c in cols)):
            w.writerow([f"{row[0]:.4f}", f"{row[1]:.4f}"] + [f"{x:.7g}" for x in row[2:]])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ropemon.lab.testbed", description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="CSV to write")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scenario", help="run this scenario's hidden seal ([plant.friction]) "
                    "instead of the example seal PAPER_SEAL")
    ap.add_argument("--rope", type=int, help="with --scenario: this rope's seal (its force_scale); default scale 1")
    ap.add_argument("--no-presliding", action="store_true", help="leave out the slow reversals")
    ap.add_argument("--truth", action="store_true", help="add the noiseless true_* columns")
    ap.add_argument("--scatter", type=float, default=0.0,
                    help="relative scatter of each level's friction parameters about their lines (e.g. 0.03)")
    a = ap.parse_args(argv)
    params, factory = PAPER_SEAL, None
    if a.scenario:
        from ropemon.lab.plant.scenario import ScenarioError
        try:
            params, factory = scenario_seal(a.scenario, a.rope)
        except ScenarioError as e:
            print(f"python -m ropemon.lab.testbed: {e}", file=sys.stderr)
            return 2
    data = run(params, presliding=not a.no_presliding, seed=a.seed, seal_scatter=a.scatter,
               law_factory=factory, presliding_period_s=presliding_period_s(params))
    write_csv(a.out, data, truth_columns=a.truth)
    print(f"{a.out}: {len(data['time_s'])} records, {len(PRESSURES_MPA)} pressure levels", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
