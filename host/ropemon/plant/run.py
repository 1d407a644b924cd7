"""Run a built scenario: integrate, then compute every truth quantity at the node's sample times."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ropemon.plant.kernel import integrate_fast
from ropemon.plant.model import G
from ropemon.plant.scenario import Scenario


@dataclass
class Result:
    scenario: Scenario
    t: np.ndarray                 # sample times (s), k / sample_hz
    truth: dict[str, np.ndarray]  # arrays at the sample times, first axis time
    wall_s: float

    @property
    def realtime_factor(self) -> float:
        return self.scenario.duration_s / self.wall_s if self.wall_s > 0 else float("inf")


def simulate(sc: Scenario, progress: Callable[[int, int], None] | None = None) -> Result:
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
    return Result(sc, ts, truth, wall)
