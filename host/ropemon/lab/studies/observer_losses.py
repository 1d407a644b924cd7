"""`ropemon study observer-losses RUN [RUN ...]`: where the friction error comes from, stage by stage.

For each run directory (`out/evaluate/runs/NAME`, as `ropemon evaluate --out out/evaluate`
left it) the node's LuGre (`ropemon.commission.reference.lugre_friction`, with the
commissioned friction fit) is driven by:

1. the plant's true piston position, no noise and no filter: the model and its
   discretisation alone;
2. that position through the node's pressure tracker (`bounce_hz`, docs/model.md),
   the filter the LuGre position has;
3. that, with the node's play (the one it holds for all channels healthy) on the
   dissipation;
4. the node's observer on the sensor stream: the float reference's friction,
   noise and all (`lugre-p`'s);
5. and 6. the two halves of the node's LuGre apart: its elastic path (the
   LuGre position's increments) with the true piston's increments as the
   dissipation path, and the other way round.

Each stage's friction takes the place of the plant's seal friction in the true
tension, so the figures (as `ropemon evaluate` scores them, % of rated rope
tension and of the true total) are the friction's alone. Stages 1-3 take the
pressure and velocity of the true position; stage 4 what the node has; stages
5 and 6 the true pressure and the velocity of their elastic path. Prints a Markdown
table (docs/model.md, "Pressure tracker": what limits the pithead figure).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ropemon.commission import reference
from ropemon.commission.nodejson import physical_params
from ropemon.lab import metrics as M
from ropemon.lab.rundir import RunDir
from ropemon.lab.studies import fmt

STAGES = ("LuGre on the true piston position",
          "+ the pressure tracker",
          "+ the play",
          "the node's observer on the sensors",
          "the node's elastic path, the true dissipation path",
          "the true elastic path, the node's dissipation path")


def play_increments(x: np.ndarray, width: float) -> np.ndarray:
    """Per-sample increments [sample, rope] of a play (backlash) of half-width `width` on x."""
    out = np.zeros_like(x)
    xp = x[0].copy()
    for j in range(1, len(x)):
        d = np.where(x[j] > xp + width, x[j] - width - xp, np.where(x[j] < xp - width, x[j] + width - xp, 0.0))
        xp += d
        out[j] = d
    return out


def stage_friction(ph: dict, truth, k: int, recs: np.ndarray) -> list[np.ndarray]:
    """Friction [sample, rope] (N) of each stage (`STAGES`)."""
    pp = physical_params(ph)
    fs = float(ph["sample_hz"])
    fr = ph["friction"]
    x = np.asarray(truth["piston_x_m"], float)[:k]
    p = np.clip(np.asarray(truth["p_tap_Pa"], float)[:k], 0.0, pp["p_max_pa"])
    if pp["tracker"] is None:
        raise SystemExit("observer-losses: the run's node has no compliance (no pressure tracker)")
    x_lp = np.empty_like(x)
    for i in range(x.shape[1]):  # the tracker is linear: it filters a position as a pressure
        tracker = reference.PressureTracker(pp["tracker"])
        x_lp[:, i] = [tracker.step(v) for v in x[:, i].tolist()]

    def inc(v: np.ndarray) -> np.ndarray:
        return np.diff(v, axis=0, prepend=v[:1])

    def lugre(dxs: np.ndarray, dxp: np.ndarray) -> np.ndarray:
        return np.stack([reference.lugre_friction(fr, p[:, i], dxs[:, i], dxp[:, i], dxs[:, i] * fs, fs)
                         for i in range(x.shape[1])], axis=1)

    d_true, d_lp = inc(x), inc(x_lp)
    obs: dict = {}
    comp = reference.compensate(ph, recs, increments=obs)
    node = np.where(comp.good, comp.friction_n, np.nan)
    return [lugre(d_true, d_true), lugre(d_lp, d_lp), lugre(d_lp, play_increments(x_lp, pp["plays_m"][-1])), node,
            lugre(obs["dxs"], d_true), lugre(d_true, obs["dxp"])]


def losses(run: RunDir) -> list[dict]:
    """The figures of each stage on one evaluate run directory."""
    ph = run.physical
    k = run.length
    sc = run.scoring(ph)
    f_true = np.asarray(run.truth["friction_N"], float)[:k]
    out = []
    for label, f in zip(STAGES, stage_friction(ph, run.truth, k, run.records[:k])):
        est = sc.truth_n - f_true + f
        fig = M.evaluate_estimate(est, sc.truth_n, sc.rated_n, sc.phase, sc.excluded, sc.steady, sc.payload_kg)
        out.append({"stage": label, **{key: fig.get(key) for key in (
            "rope_rms_pct", "rope_peak_pct", "pithead_empty_total_pct", "pithead_arrival_total_pct")}})
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("runs", nargs="+", type=Path, metavar="RUN", help="run directories (out/evaluate/runs/SCENARIO)")


def run(args: argparse.Namespace) -> int:
    print("| scenario | the LuGre driven by | rope RMS % | rope peak % | pithead empty % | pithead as arrived % |")
    print("|---|---|---:|---:|---:|---:|")
    for path in args.runs:
        for row in losses(RunDir(path)):
            print(f"| {path.name} | {row['stage']} | {row['rope_rms_pct']:.2f} | {row['rope_peak_pct']:.2f} | "
                  f"{fmt(row['pithead_empty_total_pct'], sign=True)} | "
                  f"{fmt(row['pithead_arrival_total_pct'], sign=True)} |")
    return 0
