"""`ropemon simulate SCENARIO [--out DIR] [--seed N]`: run a scenario, write truth and sensor streams."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ropemon.lab.plant.output import write_outputs
from ropemon.lab.plant.run import Result, simulate
from ropemon.lab.plant.scenario import ScenarioError, load_scenario


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario TOML file (scenarios/*.toml)")
    p.add_argument("--out", default=None, help="output directory (default out/simulate/<scenario name>)")
    p.add_argument("--seed", type=int, default=None, help="sensor noise seed (default: the scenario's)")
    p.add_argument("--quiet", action="store_true", help="no progress, no summary")


def summarize(res: Result) -> dict[str, Any]:
    """Key figures: per rest phase, true total tension, static load and the raw p_tap*A sum at its end."""
    sc = res.scenario
    tr = res.truth
    rests = []
    for ph in sc.phases:
        if ph.kind not in ("rest", "bench"):
            continue
        k = int(min(np.searchsorted(res.t, ph.t1 - 1e-9) - 1, len(res.t) - 1))
        total = float(tr["tension_N"][k].sum())
        raw = float((tr["p_tap_Pa"][k] * sc.plant.A).sum())
        rests.append({"label": ph.label or ph.kind, "t_s": float(res.t[k]), "tension_sum_N": total,
                      "static_load_N": float(tr["load_N"][k]), "raw_pA_sum_N": raw,
                      "raw_error_pct": 100.0 * (raw - total) / total if total else 0.0})
    T = tr["tension_N"]
    mean = T.mean(axis=1, keepdims=True)
    dev = np.where(mean > 0, np.abs(T - mean) / np.where(mean > 0, mean, 1.0), 0.0)
    return {"duration_s": sc.duration_s, "samples": len(res.t), "wall_s": res.wall_s,
            "realtime_factor": res.realtime_factor, "max_tension_N": float(T.max()),
            "min_tension_N": float(T.min()), "max_imbalance_frac": float(dev.max()),
            "piston_x_range_m": [float(tr["piston_x_m"].min()), float(tr["piston_x_m"].max())],
            "rests": rests}


def run(args: argparse.Namespace) -> int:
    try:
        sc = load_scenario(args.scenario, seed=args.seed)
    except ScenarioError as e:  # a field's fault, or the file's (which names it already)
        where = "" if str(e).startswith(str(args.scenario)) else f"{args.scenario}: "
        print(f"ropemon simulate: {where}{e}", file=sys.stderr)
        return 1
    out = Path(args.out) if args.out else Path("out") / "simulate" / sc.name
    show = not args.quiet and sc.duration_s > 5.0 and sys.stderr.isatty()
    t0 = time.perf_counter()

    def progress(k: int, K: int) -> None:
        el = time.perf_counter() - t0
        print(f"\r  simulating {sc.name}: {100 * k // K:3d} %  ({k / K * sc.duration_s:6.1f} of "
              f"{sc.duration_s:.1f} s simulated, {el:5.1f} s)", end="", file=sys.stderr, flush=True)

    try:
        res = simulate(sc, progress if show else None)
    except FloatingPointError as e:
        print(f"ropemon simulate: {sc.name}: {e}", file=sys.stderr)
        return 1
    if show:
        print("\r" + " " * 78 + "\r", end="", file=sys.stderr)
    summary = summarize(res)
    written = write_outputs(res, out, summary)
    if not args.quiet:
        print(f"{sc.name}: {sc.duration_s:.1f} s simulated ({sc.rig}, {sc.plant.n} cylinders, step "
              f"{sc.step_s * 1e3:g} ms, {sc.sample_hz} Hz samples) in {res.wall_s:.2f} s "
              f"({res.realtime_factor:.0f}x real time)")
        print(f"  tension {summary['min_tension_N'] / 1e3:.2f} .. {summary['max_tension_N'] / 1e3:.2f} kN per rope, "
              f"largest deviation from the mean {100 * summary['max_imbalance_frac']:.1f} %, pistons "
              f"{summary['piston_x_range_m'][0] * 1e3:.1f} .. {summary['piston_x_range_m'][1] * 1e3:.1f} mm")
        for r in summary["rests"]:
            print(f"  {r['label']:<24} t={r['t_s']:7.1f} s  true sum {r['tension_sum_N'] / 1e3:7.2f} kN  "
                  f"raw p*A {r['raw_pA_sum_N'] / 1e3:7.2f} kN ({r['raw_error_pct']:+.1f} %)")
        print("  wrote " + ", ".join(str(p) for p in written))
    return 0
