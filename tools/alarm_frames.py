"""Where the deviation-alarm errors of a scenario's `lugre-p+loss` run fall.

Reruns the float reference on a scenario's run directory as `ropemon evaluate`
left it (`RUN/sim/sensors.rsens`, `RUN/sim/truth.npz`, `RUN/node-evaluated.json`)
and lists the frames (10 Hz windows) where, with a real 8 % deviation of some
rope superposed, another level of the alarm is raised falsely, or a real 12 %
deviation is not seen (the assessment of `ropemon.lab.metrics.alarm_assessment`,
counted once per frame whatever the rope and sign): by phase of the wind, by
the ropes' mean tension, and as episodes (frames less than 0.5 s apart); then
the operator alarms those frames make through the host's debounce
(`alarm_assessment` with the frame period), and the narrowest margin of the
8 % test: the largest deviation the estimate reads, outside shock windows,
with one rope truly 8 % off the mean.

`--noise-scale F` first scales the pressure channels' noise by F, the config
commissioned with it, as `tools/pithead_spread.py --scale` does; `--set KEY=VALUE`
(JSON) changes a setting of the commissioned `physical` section.

    .venv/bin/python tools/alarm_frames.py out/evaluate/runs/duty-cycle-50
    .venv/bin/python tools/alarm_frames.py RUN --noise-scale 0.25 --set friction_play_sigmas=1.6
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

sys.path.insert(0, str(Path(__file__).resolve().parent))  # its sibling, however this was loaded
import pithead_spread as PS  # noqa: E402


def alarm_frames(est_n: np.ndarray, truth_n: np.ndarray, window: int, threshold: float = 0.10) -> dict:
    """Boolean per frame: 'false' (at 8 %) and 'missed' (at 12 %), any rope and sign."""
    n = len(truth_n) // window
    out = {"false": np.zeros(n, bool), "missed": np.zeros(n, bool)}
    for level, kind in ((0.08, "false"), (0.12, "missed")):
        for rope in range(truth_n.shape[1]):
            for sign in (1.0, -1.0):
                step = M.deviation_step_n(truth_n, rope, sign * level)
                t, e = truth_n.copy(), est_n.copy()
                t[:, rope] += step
                e[:, rope] += step
                de = M.deviation_from_mean(M.window_means(e, window))[:n]
                dt = M.deviation_from_mean(M.window_means(t, window))[:n]
                flag = np.abs(de) > threshold
                if kind == "false":
                    out[kind] |= (flag & (np.abs(dt) < threshold - 1e-3)).any(axis=1)
                else:
                    out[kind] |= (np.abs(dt[:, rope]) > threshold + 1e-3) & ~flag[:, rope]
    return out


def largest_at_8(est_n: np.ndarray, truth_n: np.ndarray, window: int,
                 excluded: np.ndarray | None = None) -> tuple[float, int, int]:
    """(|deviation|, rope, frame): the largest deviation from the mean the estimate reads
    in a frame outside shock windows while one rope is truly 8 % off (any rope, either sign)."""
    n = len(truth_n) // window
    keep = np.ones(n, bool) if excluded is None else (
        M.window_means(np.asarray(excluded, float), window)[:n] == 0.0)
    best = (0.0, -1, -1)
    for rope in range(truth_n.shape[1]):
        for sign in (1.0, -1.0):
            step = M.deviation_step_n(truth_n, rope, sign * 0.08)
            e = est_n.copy()
            e[:, rope] += step
            de = np.abs(M.deviation_from_mean(M.window_means(e, window))[:n])
            de[~keep] = 0.0
            de = np.nan_to_num(de)
            f, r = np.unravel_index(np.argmax(de), de.shape)
            if de[f, r] > best[0]:
                best = (float(de[f, r]), int(r), int(f))
    return best


def inputs(run: Path, noise_scale: float = 1.0, settings: dict | None = None) -> tuple:
    """(physical, hz, records, truth) of a run directory, its pressure noise scaled by
    `noise_scale` (the config commissioned with it) and `settings` put in `physical`."""
    ph = json.loads((run / "node-evaluated.json").read_text())["physical"]
    _r, hz, recs = reference.read_rsens(run / "sim" / "sensors.rsens")
    with np.load(run / "sim" / "truth.npz") as z:
        truth = {key: z[key] for key in z.files}
    k = min(len(recs), len(truth["tension_N"]))
    recs, truth = recs[:k], {key: v[:k] for key, v in truth.items()}
    if noise_scale != 1.0:
        seed = int(json.loads((run / "sim" / "truth.json").read_text())["seed"])
        recs, ph = PS.scaled_pressure_noise(PS.Wind(seed, recs, truth, ph, hz), noise_scale)
    return {**ph, **(settings or {})}, hz, recs, truth


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="a scenario's directory under out/evaluate/runs")
    ap.add_argument("--noise-scale", type=float, default=1.0, metavar="F",
                    help="the pressure channels' noise times F, commissioned with it")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="change a setting of the physical section (JSON value); repeatable")
    a = ap.parse_args(argv)
    settings = {}
    for key, values in PS.parse_set(a.set):
        if len(values) != 1:
            ap.error(f"--set {key}: one value")
        settings[key] = values[0]
    ph, hz, recs, truth = inputs(a.run, a.noise_scale, settings)
    truth_n = np.asarray(truth["tension_N"], float)
    window = hz // int(ph["frame_hz"])
    est = reference.compensate(ph, recs).tension_n
    phase = M.classify_phases(truth["cage_depth_m"], truth["wheel_speed_m_s"],
                              truth["wheel_accel_m_s2"], float(ph["hall_marks_m"][-1]))[::window]
    frames = alarm_frames(est, truth_n, window)
    _phase, excluded, _steady, _payload = EV.scoring_masks(truth, truth_n, hz, float(ph["rated_rope_tension_N"]),
                                                           float(ph["hall_marks_m"][-1]))
    operator = M.alarm_assessment(est, truth_n, excluded, window, frame_s=window / hz)
    mean_kn = M.window_means(truth_n, window).mean(axis=1) / 1e3
    n = len(frames["false"])
    changed = (f", pressure noise x{a.noise_scale:g}" if a.noise_scale != 1.0 else "") + "".join(
        f", {key}={json.dumps(v)}" for key, v in settings.items())
    print(f"{a.run}{changed}: {n} frames, the ropes' mean tension median {np.median(mean_kn[:n]):.1f} kN")
    for kind, label in (("false", "false at 8 %"), ("missed", "missed at 12 %")):
        idx = np.where(frames[kind])[0]
        by_phase = np.bincount(phase[idx], minlength=len(M.PHASES))
        print(f"{label}: {len(idx)} frames; by phase "
              + ", ".join(f"{p} {c}" for p, c in zip(M.PHASES, by_phase) if c)
              + (f"; mean rope tension median {np.median(mean_kn[idx]):.1f} kN" if len(idx) else ""))
        if len(idx):
            episodes = np.split(idx, np.where(np.diff(idx) > 5)[0] + 1)
            print(f"  {len(episodes)} episodes, starting at (s): "
                  + " ".join(f"{e[0] / (hz / window):.1f}" for e in episodes))
    print(f"operator alarms (the host's debounce, shock windows left out): "
          f"{operator['8']['false_alarms']} false at 8 %, "
          f"{operator['12']['missed_alarm_frames']} missed alarm frames at 12 %")
    dev, rope, frame = largest_at_8(est, truth_n, window, excluded)
    print(f"narrowest margin at 8 %: with one rope truly 8 % off, the estimate reads at most "
          f"{100 * dev:.2f} % (rope {rope + 1}, {frame * window / hz:.1f} s; 10 % raises the flag)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
