"""Run a built scenario: integrate, then compute every truth quantity at the node's sample times."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ropemon.lab.plant.stepper import integrate_fast
from ropemon.lab.plant.model import G
from ropemon.lab.plant.scenario import Scenario


class TruthError(FloatingPointError):
    """A simulated truth outside its seal law's physical bounds (`check_truth`): a numerical
    failure, never to be written or scored (`ropemon simulate` and `evaluate.simulate` report
    it as they report a non-finite state)."""


FRICTION_TOL = 1.2          # |F| at most this x force_scale (Fs(p) + sigma2(p) |v|)
PRESSURE_TOL_PA = 1.0e5     # no cavity pressure below -this (gauge: below vacuum)


def check_truth(friction, truth: dict, t, tol: float = FRICTION_TOL, p_tol_Pa: float = PRESSURE_TOL_PA) -> None:
    """Raise TruthError (naming the rope, from 1, the time and the ratio) where a truth is physically
    impossible: a rope's seal friction |F| beyond tol x its force_scale x (Fs(p) + sigma2(p) |v|)
    (p the cavity pressure clamped at 0; the scale is truth `seal_scale` where given, so a seized
    seal's factor counts; laws with an Fs line, i.e. every law here: LuGre's and
    elasto-plastic's sigma0 z stays within s(v, p) <= Fs, Maxwell-slip's elements within alpha_j s,
    Coulomb-Stribeck's g tanh as well), or a cavity pressure below -p_tol_Pa. A seal law that ran
    away in the integrator (population-148's elasto-plastic seal before the settled Newton step:
    299 Fs, -20 MPa) is so refused rather than scored. truth: `Result.truth`'s arrays
    (friction_N, p_cav_Pa, piston_v_m_s; time first, then rope), t: their times (s)."""
    p = np.asarray(truth["p_cav_Pa"], dtype=float)
    t = np.asarray(t, dtype=float)
    if not np.all(np.isfinite(p)):
        raise TruthError("the cavity pressure is not finite")
    if p.size and p.min() < -p_tol_Pa:
        k, i = np.unravel_index(np.argmin(p), p.shape)
        raise TruthError(f"rope {i + 1}: cavity pressure {p[k, i] / 1e6:.3g} MPa at t = {t[k]:.3f} s, below "
                         f"-{p_tol_Pa / 1e6:g} MPa (a seal law or the integrator ran away)")
    fs_line, s2_line = getattr(friction, "Fs", None), getattr(friction, "sigma2", None)
    if fs_line is None or s2_line is None:
        return
    F = np.asarray(truth["friction_N"], dtype=float)
    v = np.asarray(truth["piston_v_m_s"], dtype=float)
    pm = np.maximum(p, 0.0) * 1e-6
    if "seal_scale" in truth:   # the seal's scale at each sample (a seized seal's factor from its onset)
        scale = np.asarray(truth["seal_scale"], dtype=float)
    else:
        scale = 1.0 if friction.force_scale is None else np.asarray(friction.force_scale, dtype=float)
    bound = scale * (fs_line.at(pm) + s2_line.at(pm) * np.abs(v))
    if not np.all(np.isfinite(F)):
        raise TruthError("the seal friction is not finite")
    ratio = np.abs(F) / np.maximum(bound, 1e-300)
    if ratio.size and ratio.max() > tol:
        k, i = np.unravel_index(np.argmax(ratio), ratio.shape)
        raise TruthError(f"rope {i + 1}: seal friction {F[k, i]:.6g} N at t = {t[k]:.3f} s is {ratio[k, i]:.3g} x "
                         f"force_scale (Fs(p) + sigma2(p) |v|) = {bound[k, i]:.6g} N, beyond {tol:g} "
                         f"(law {friction.name}: the seal law ran away in the integrator)")


@dataclass
class Result:
    scenario: Scenario
    t: np.ndarray                 # sample times (s), k / sample_hz
    truth: dict[str, np.ndarray]  # arrays at the sample times, first axis time
    wall_s: float

    @property
    def realtime_factor(self) -> float:
        return self.scenario.duration_s / self.wall_s if self.wall_s > 0 else float("inf")


def simulate(sc: Scenario, progress: Callable[[int, int], None] | None = None, check: bool = True) -> Result:
    """Integrate the scenario and sample its truth; with check (default) the truth must pass
    `check_truth` (else TruthError, a FloatingPointError)."""
    t0 = time.perf_counter()
    Y = integrate_fast(sc.plant, sc.inputs, sc.plant.rest_state(sc.inputs), sc.steps.tolist(), progress,
                       method=sc.method)
    wall = time.perf_counter() - t0
    u = sc.inputs.take(sc.steps)
    grid = sc.plant.outputs(u, Y)
    grid.update(oil_temp_C=u.oil_temp_C, payload_kg=u.payload_kg, load_N=u.m_weight * G if sc.rig == "hoist"
                else u.f_load.sum(axis=1), pump_m3_s=u.q_pump)
    if sc.rig == "hoist":
        grid.update(wheel_depth_m=u.s_wheel, wheel_speed_m_s=u.u_wheel, wheel_accel_m_s2=u.a_wheel)
    else:
        grid.update(load_input_N=u.f_load)
    n_samples = int(np.floor(sc.duration_s * sc.sample_hz + 1e-9)) + 1
    ts = np.arange(n_samples) / sc.sample_hz
    if len(u.t) == n_samples and np.allclose(u.t, ts, rtol=0, atol=1e-9):
        truth = dict(grid)
    else:  # samples between step points: linear interpolation
        truth = {}
        for k, v in grid.items():
            if v.ndim == 1:
                truth[k] = np.interp(ts, u.t, v)
            else:
                flat = v.reshape(len(v), -1)
                truth[k] = np.stack([np.interp(ts, u.t, flat[:, i]) for i in range(flat.shape[1])],
                                    axis=1).reshape((len(ts),) + v.shape[1:])
    if check:
        check_truth(sc.plant.friction, truth, ts)
    return Result(sc, ts, truth, wall)
