"""`ropemon study balancing-strokes RUN`: how the pistons share the oil's common motion, from a
simulated wind's truth.

Reads the run directory's truth (`ropemon.lab.rundir`; a simulator's output is enough) and
prints, in 1 s blocks: how well `sum_i dx_i` equals the oil's compression `N k dp` (the
connecting assembly shares the oil; k the plant's compliance per cylinder), and how the
motion is shared where the pistons move (at least 10 um together): the largest share of
one piston, and the balancing strokes (one piston taking more than half of it). The
figures of docs/model.md, "Balancing strokes".
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ropemon.lab.rundir import RunDir

K_M_PER_PA = 0.30e-9  # the plant's compliance per cylinder (docs/simulator.md), equal areas


def analyse(truth, sample_hz: int, k_m_per_pa: float = K_M_PER_PA, min_move_m: float = 10e-6) -> dict:
    x = np.asarray(truth["piston_x_m"], float)
    p = np.asarray(truth["p_cav_Pa"], float).mean(axis=1)
    n_ropes = x.shape[1]
    blocks = len(x) // sample_hz
    dx = np.diff(x[: blocks * sample_hz: sample_hz], axis=0)
    dp = np.diff(p[: blocks * sample_hz: sample_hz])
    total = dx.sum(axis=1)
    moving = np.abs(total) > min_move_m
    share = dx[moving] / total[moving][:, None]
    largest = share.max(axis=1)
    stroke = largest > 0.5
    return {
        "seconds": int(blocks - 1),
        "sum_dx_vs_compression_rms_um": float(np.sqrt(np.mean((total - n_ropes * k_m_per_pa * dp) ** 2)) * 1e6),
        "sum_dx_rms_um": float(np.sqrt(np.mean(total ** 2)) * 1e6),
        "moving_seconds": int(moving.sum()),
        "largest_share_histogram": dict(zip(["<0.3", "0.3-0.4", "0.4-0.6", "0.6-0.8", "0.8-0.95", "0.95-1.05", ">1.05"],
                                            np.histogram(largest, bins=[0, 0.3, 0.4, 0.6, 0.8, 0.95, 1.05, 1e9])[0]
                                            .tolist())),
        "stroke_seconds": int(stroke.sum()),
        "stroke_seconds_per_rope": np.bincount(share[stroke].argmax(axis=1), minlength=n_ropes).tolist(),
    }


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", type=Path, metavar="RUN", help="a run directory (out/evaluate/runs/SCENARIO)")


def run(args: argparse.Namespace) -> int:
    wind = RunDir(args.run)
    r = analyse(wind.truth, wind.sample_hz)
    print(f"{args.run}: {r['seconds']} s")
    print(f"sum of piston motion against the oil's compression N k dp: {r['sum_dx_vs_compression_rms_um']:.2f} um rms "
          f"per second (the motion itself: {r['sum_dx_rms_um']:.1f} um rms)")
    print(f"seconds where the pistons move >= 10 um together: {r['moving_seconds']}; largest share of one piston: "
          + ", ".join(f"{k} {v}" for k, v in r["largest_share_histogram"].items()))
    print(f"balancing strokes (one piston > half of it): {r['stroke_seconds']} s, per rope "
          f"{r['stroke_seconds_per_rope']}")
    return 0
