"""Where the friction error comes from, stage by stage, on `ropemon evaluate` runs.

For each run directory (`out/evaluate/runs/NAME`, as `ropemon evaluate` left it)
the node's LuGre (`ropemon.commission.reference.lugre_friction`, with the commissioned
friction fit) is driven by:

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
5 and 6 the true pressure and the velocity of their elastic path.
Prints a Markdown table (notes/accuracy-research.md, "What limits the pithead figure").

    .venv/bin/python tools/observer_losses.py out/evaluate/runs/payload-12t [RUN ...]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ropemon.lab import evaluate as EV
from ropemon.lab import metrics as M
from ropemon.commission import reference
from ropemon.commission.nodeconfig import physical_params

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
    """Friction [sample, rope] (N) of each of the four stages."""
    pp = physical_params(ph)
    fs = float(ph["sample_hz"])
    fr = ph["friction"]
    x = np.asarray(truth["piston_x_m"], float)[:k]
    p = np.clip(np.asarray(truth["p_tap_Pa"], float)[:k], 0.0, pp["p_max_pa"])
    if pp["tracker"] is None:
        raise SystemExit("observer_losses: the run's node has no compliance (no pressure tracker)")
    x_lp = np.empty_like(x)
    for i in range(x.shape[1]):  # the tracker is linear: it filters a position as a pressure
        tracker = reference.PressureTracker(pp["tracker"])
        x_lp[:, i] = [tracker.step(v) for v in x[:, i].tolist()]

    def inc(v: np.ndarray) -> np.ndarray:
        return np.diff(v, axis=0, prepend=v[:1])

    def run(dxs: np.ndarray, dxp: np.ndarray) -> np.ndarray:
        return np.stack([reference.lugre_friction(fr, p[:, i], dxs[:, i], dxp[:, i], dxs[:, i] * fs, fs)
                         for i in range(x.shape[1])], axis=1)

    d_true, d_lp = inc(x), inc(x_lp)
    obs: dict = {}
    comp = reference.compensate(ph, recs, increments=obs)
    node = np.where(comp.good, comp.friction_n, np.nan)
    return [run(d_true, d_true), run(d_lp, d_lp), run(d_lp, play_increments(x_lp, pp["plays_m"][-1])), node,
            run(obs["dxs"], d_true), run(d_true, obs["dxp"])]


def losses(run_dir: Path) -> list[dict]:
    """The figures of each stage on one evaluate run directory."""
    ph = json.loads((run_dir / EV.NODE_EVALUATED).read_text())["physical"]
    _r, hz, recs = reference.read_rsens(run_dir / "sim" / "sensors.rsens")
    truth = np.load(run_dir / "sim" / "truth.npz")
    truth_n = np.asarray(truth["tension_N"], float)[: len(recs)]
    k = len(truth_n)
    recs = recs[:k]
    rated = float(ph["rated_rope_tension_N"])
    phase, excluded, steady, payload = EV.scoring_masks(truth, truth_n, hz, rated, float(ph["hall_marks_m"][-1]))
    f_true = np.asarray(truth["friction_N"], float)[:k]
    out = []
    for label, f in zip(STAGES, stage_friction(ph, truth, k, recs)):
        est = truth_n - f_true + f
        fig = M.evaluate_estimate(est, truth_n, rated, phase, excluded, steady, payload)
        out.append({"stage": label, **{key: fig.get(key) for key in (
            "rope_rms_pct", "rope_peak_pct", "pithead_empty_total_pct", "pithead_arrival_total_pct")}})
    return out


def _fmt(v) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:+.2f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="scenario directories under out/evaluate/runs")
    a = ap.parse_args(argv)
    print("| scenario | the LuGre driven by | rope RMS % | rope peak % | pithead empty % | pithead as arrived % |")
    print("|---|---|---:|---:|---:|---:|")
    for run_dir in a.runs:
        for row in losses(run_dir):
            print(f"| {run_dir.name} | {row['stage']} | {row['rope_rms_pct']:.2f} | {row['rope_peak_pct']:.2f} | "
                  f"{_fmt(row['pithead_empty_total_pct'])} | {_fmt(row['pithead_arrival_total_pct'])} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
