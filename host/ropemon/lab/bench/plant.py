"""Plant simulator benchmark: wall time and real-time factor of the field trip, against scipy's
solve_ivp (BDF, Radau) on the same model at the same accuracy, measured in the same run.

Accuracy is the largest rope-tension error against a reference run (the scenario's method,
BDF2 by default, with every step quartered). The baseline's rtol is lowered from 1e-2 until its error is no larger than ours.
"""
from __future__ import annotations

import os
import statistics
import time
import tomllib
from pathlib import Path

import numpy as np

from ropemon.lab.plant.stepper import integrate_fast
from ropemon.lab.plant.scenario import build, load_scenario
from ropemon.lab.plant.solver import integrate_solve_ivp

SCENARIOS = Path(__file__).resolve().parents[4] / "scenarios"


def _outputs_at(sc, Y, grid_idx, ts, key):
    T = sc.plant.outputs(sc.inputs.take(grid_idx), Y)[key]
    t = sc.inputs.t[grid_idx]
    return np.stack([np.interp(ts, t, T[:, i]) for i in range(T.shape[1])], axis=1)


def _tensions_at(sc, Y, grid_idx, ts):
    return _outputs_at(sc, Y, grid_idx, ts, "tension_N")


def _errors(sc, Y, grid_idx, ts, ref):
    """Largest |tension - reference| and |friction - reference| (N)."""
    return tuple(float(np.abs(_outputs_at(sc, Y, grid_idx, ts, key) - ref[key]).max())
                 for key in ("tension_N", "friction_N"))


def _scaled(path: Path, f: int):
    with path.open("rb") as fh:
        doc = tomllib.load(fh)
    sc0 = build(doc, path)
    d = dict(doc)
    d["step_s"] = sc0.step_s / f
    d["max_step_s"] = sc0.max_step_s / f
    d["bounce_rad_per_step"] = sc0.bounce_rad_per_step / f
    return build(d, path)


def duty_cycle(trips: int, window_s: float = 60.0) -> dict:
    """Integrate `trips` winds of scenarios/duty-cycle.toml window by window, keeping only the state
    (inputs for one window at a time: 100 trips would not fit in memory at once)."""
    path = SCENARIOS / "duty-cycle.toml"
    with path.open("rb") as fh:
        doc = tomllib.load(fh)
    doc["duty"]["trips"] = trips
    sc = build(doc, path, eager=False)
    h = sc.step_s
    K = sc.grid_points
    win = int(round(window_s / h))
    t0 = time.perf_counter()
    c0 = time.process_time()
    y = None
    k0 = 0
    steps = 0
    while k0 < K - 1:
        k1 = min(k0 + win, K - 1)
        u = sc.make_inputs(np.arange(k0, k1 + 1) * h)
        if y is None:
            y = sc.plant.rest_state(u)
        plan = sc.plan_steps(u).tolist()
        steps += len(plan) - 1
        y = integrate_fast(sc.plant, u, y, plan, keep=False, method=sc.method)[-1]
        k0 = k1
    return {"trips": trips, "simulated_s": sc.duration_s, "steps": steps, "wall_s": time.perf_counter() - t0,
            "cpu_s": time.process_time() - c0}


def measure(quick: bool = False) -> dict:
    name = "short-test" if quick else "paper-field-trip"
    path = SCENARIOS / f"{name}.toml"
    repeats = 1 if quick else 3
    load_before = os.getloadavg()[0]
    sc = load_scenario(path)
    y0 = sc.plant.rest_state(sc.inputs)
    steps = sc.steps.tolist()
    walls, cpus = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        Y = integrate_fast(sc.plant, sc.inputs, y0, steps, method=sc.method)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    wall = statistics.median(walls)
    ts = np.arange(0.0, sc.duration_s, 1.0 / sc.sample_hz)
    # reference: every step quartered
    ref_sc = _scaled(path, 4)
    Yr = integrate_fast(ref_sc.plant, ref_sc.inputs, ref_sc.plant.rest_state(ref_sc.inputs), ref_sc.steps.tolist(),
                        method=ref_sc.method)
    ref = {key: _outputs_at(ref_sc, Yr, ref_sc.steps, ts, key) for key in ("tension_N", "friction_N")}
    err, err_F = _errors(sc, Y, sc.steps, ts, ref)
    # convergence: every step halved
    half_sc = _scaled(path, 2)
    Yh = integrate_fast(half_sc.plant, half_sc.inputs, half_sc.plant.rest_state(half_sc.inputs), half_sc.steps.tolist(),
                        method=half_sc.method)
    halving = float(np.abs(_tensions_at(sc, Y, sc.steps, ts) - _tensions_at(half_sc, Yh, half_sc.steps, ts)).max())
    halving_F = float(np.abs(_outputs_at(sc, Y, sc.steps, ts, "friction_N")
                             - _outputs_at(half_sc, Yh, half_sc.steps, ts, "friction_N")).max())
    # the former method, ROS2, on the same step plan (why it was replaced: the friction)
    t0 = time.perf_counter()
    Yo = integrate_fast(sc.plant, sc.inputs, y0, steps, method="ros2")
    ros2 = {"wall_s": time.perf_counter() - t0}
    ros2["error_N"], ros2["friction_error_N"] = _errors(sc, Yo, sc.steps, ts, ref)
    # baseline: solve_ivp on the numpy model, same inputs, analytic Jacobian, rtol lowered until
    # both its tension and its friction errors are no larger than ours
    base = {}
    grid = np.arange(len(sc.inputs.t))
    for method in ("BDF", "Radau"):
        for rtol in (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7):
            t0 = time.perf_counter()
            Yb, nfev = integrate_solve_ivp(sc.plant, sc.inputs, y0, sc.inputs.t, method=method, rtol=rtol)
            wb = time.perf_counter() - t0
            eb, eb_F = _errors(sc, Yb, grid, ts, ref)
            if (eb <= err and eb_F <= err_F) or rtol == 1e-7:
                base[method] = {"wall_s": wb, "rtol": rtol, "error_N": eb, "friction_error_N": eb_F,
                                "nfev": int(nfev)}
                break
    best = min(base, key=lambda m: base[m]["wall_s"])
    duty = duty_cycle(2 if quick else 100)
    return {
        "scenario": name, "simulated_s": sc.duration_s, "steps": len(steps), "repeats": repeats,
        "wall_s": wall, "cpu_s": statistics.median(cpus), "realtime_factor": sc.duration_s / wall,
        "realtime_factor_cpu": sc.duration_s / statistics.median(cpus),
        "method": sc.method, "error_N": err, "friction_error_N": err_F, "rated_N": sc.rated_rope_tension_N,
        "halving_max_dT_N": halving, "halving_max_dF_N": halving_F, "ros2_same_steps": ros2,
        "duty_cycle": duty,
        "baseline": best, "baseline_wall_s": base[best]["wall_s"], "baseline_error_N": base[best]["error_N"],
        "baseline_rtol": base[best]["rtol"], "baselines": base,
        "speedup_vs_baseline": base[best]["wall_s"] / wall,
        "loadavg_1min": [load_before, os.getloadavg()[0]], "cpus": os.cpu_count(),
    }


def describe(f: dict) -> str:
    lines = [
        f"plant simulator, {f['scenario']} ({f['simulated_s']:.1f} s simulated, {f['steps']} {f['method']} "
        f"steps, median of {f['repeats']}; errors against every step quartered):",
        f"  {f['method']} kernel      {f['wall_s']:7.2f} s wall ({f['realtime_factor']:.0f}x real time; "
        f"{f['cpu_s']:.2f} s CPU, {f['realtime_factor_cpu']:.0f}x)  max error: tension {f['error_N']:.1f} N "
        f"({100 * f['error_N'] / f['rated_N']:.3f} % of rated), friction {f['friction_error_N']:.1f} N",
    ]
    o = f["ros2_same_steps"]
    lines.append(f"  ROS2, same steps {o['wall_s']:7.2f} s wall  max error: tension {o['error_N']:.1f} N, "
                 f"friction {o['friction_error_N']:.1f} N (the former method)")
    lines.append(f"  convergence: halving every step moves rope tensions by {f['halving_max_dT_N']:.1f} N and "
                 f"friction by {f['halving_max_dF_N']:.1f} N "
                 f"({100 * max(f['halving_max_dT_N'], f['halving_max_dF_N']) / f['rated_N']:.3f} % of rated; "
                 f"the limit is 0.1 %)")
    for m, b in f["baselines"].items():
        lines.append(f"  solve_ivp {m:<6} {b['wall_s']:7.2f} s wall (rtol {b['rtol']:g}, {b['nfev']} f evals)  "
                     f"max error: tension {b['error_N']:.1f} N, friction {b['friction_error_N']:.1f} N")
    lines.append(f"  {f['method']} is {f['speedup_vs_baseline']:.1f}x faster than the best baseline "
                 f"({f['baseline']}) at no worse tension and friction accuracy")
    d = f["duty_cycle"]
    lines.append(f"  duty cycle, {d['trips']} trips ({d['simulated_s']:.0f} s simulated, {d['steps']} steps): "
                 f"{d['wall_s']:.1f} s wall ({d['simulated_s'] / d['wall_s']:.0f}x real time), {d['cpu_s']:.1f} s CPU")
    lines.append(f"  load average {f['loadavg_1min'][0]:.1f} -> {f['loadavg_1min'][1]:.1f} on {f['cpus']} CPUs "
                 f"(the machine is shared: wall times rise with load)")
    return "\n".join(lines)
