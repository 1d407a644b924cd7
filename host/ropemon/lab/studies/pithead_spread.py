"""`ropemon study pithead-spread OUT SCENARIO ... [--scale A,...] [--drift A,...] [--set KEY=V1,V2]
[--smoother F,...]`: where the pithead total's seed-to-seed spread comes from, and what would narrow it.

`ropemon study seed-spread` shows that the full compensation's pithead total moves with
the noise seed. This takes its work directory (OUT/seed-N/runs/SCENARIO: each seed's run
directory, `ropemon.lab.rundir`: the simulated wind, the truth, and the node config that
seed's commissioning made) and reruns the float reference (`lugre-p+loss`) on recombined
inputs, one experiment per row:

- as evaluated: each seed's wind with its own config (seed-spread's figure);
- seed-1 config: each seed's wind with the first seed's config (its friction
  fit, k, pressure noise and bounce; the first of `--seeds`, seed 1 by
  default): what the calibration's draw adds;
- pressure noise only / displacement noise only: the first seed's wind with
  seed N's pressure (or displacement) channels;
- pressure noise x A (`--scale A,...`): each seed's wind with its pressure noise
  scaled by A around the true tap pressure (0: a noise-free transmitter on the
  same ADC), the config's `pressure_noise_Pa` scaled to match: transmitters of
  that noise, commissioned with it (where the config refuses them, e.g. too quiet for
  the pressure tracker's gains, the row says so);
- pressure noise x A after commissioning (`--drift A,...`): the same winds with
  the config as commissioned: the transmitters' noise changed since;
- `--set KEY=V1,V2 ...`: each combination of settings of the config's
  `physical` section (JSON values), as `ropemon study observer-sensitivity` changes them,
  on the winds as evaluated and again at each `--scale` (its own tuning) and each
  `--drift` (the config as commissioned, with the setting);
- smoother, plays x F (`--smoother F,...`): each seed's wind with the tracker
  replaced by the Kalman smoother of the whole wind's median pressure (the
  tracker's own creep-and-bounce model, run forward and back: the best linear
  reading of the median a node could make with all of the wind at hand, which
  no node has), and the play, the rest play and the rest threshold scaled to
  the smoother's lower noise, times F.

Then, for one seed (`--window-seed`, default the one farthest from the first),
how much of its difference from the first each stretch of the wind's pressure
noise makes: the first seed's wind with that seed's pressure channels over one
stretch only. With several scenarios, a last table adds up the seeds within
the pithead target (`evaluate.TARGETS`) per experiment.

The figure is the pithead total error, empty cage (the paper's case), or the
arrival rest where the scenario has no empty one, in % of the true total. The
transmitters' noise figures of docs/commissioning.md and docs/model.md are its
`--scale` and `--drift` rows:

    ropemon study seed-spread paper-field-trip payload-12t --seeds 1-10 --out out/seed-spread
    ropemon study pithead-spread out/seed-spread paper-field-trip payload-12t --scale 0,0.5
    ropemon study pithead-spread out/seed-spread payload-12t --scale "" \\
        --set creep_q_Pa2_s3=3e8,3e9 --set friction_play_sigmas=0.8,1.45
    ropemon study pithead-spread out/seed-spread paper-field-trip --scale 0.5 \\
        --set friction_play_sigmas=1.45,1.6 --drift 0.9,1.1
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import statistics
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.linalg

from ropemon.commission import reference
from ropemon.commission.nodejson import (COMPLIANCE_DEFAULTS, DEFAULTS, MEDIAN_NOISE, namur_limits, pressure_noise_pa,
                                           pressure_tracker)
from ropemon.lab import metrics as M
from ropemon.lab.rundir import RunDir
from ropemon.lab.studies import parse_set, pithead_target_pct, seed_range


@dataclass
class Wind:
    """One seed's run of a scenario: records, truth (both over the samples that have both)
    and the config its commissioning made."""
    seed: int
    records: np.ndarray
    truth: Mapping       # rundir.Truth
    physical: dict
    hz: int


def load(out: Path, scenario: str, seed: int) -> Wind:
    """Seed `seed`'s run of `scenario` in seed-spread's work directory `out`."""
    run = RunDir(out / f"seed-{seed}" / "runs" / scenario)
    k = run.length
    return Wind(seed, run.records[:k], run.truth.cut(k), run.physical, run.sample_hz)


def score(physical: dict, records: np.ndarray, wind: Wind, tracker_class: type | None = None) -> dict:
    """The float reference's pithead total (%), its basis, and the rope RMS (% of rated);
    `tracker_class` in place of the node's pressure tracker (`reference.compensate`)."""
    from ropemon.lab.evaluate import scoring_masks

    truth_n = np.asarray(wind.truth["tension_N"], float)[:len(records)]
    rated = float(physical["rated_rope_tension_N"])
    phase, excluded, steady, payload = scoring_masks(wind.truth, truth_n, wind.hz, rated,
                                                     float(physical["hall_marks_m"][-1]))
    est = reference.compensate(physical, records, tracker_class=tracker_class).tension_n
    f = M.evaluate_estimate(est, truth_n, rated, phase, excluded, steady, payload)
    return {"pithead": f["pithead_total_pct"], "basis": f["pithead_total_basis"], "rms": f["rope_rms_pct"]}


def spliced(base: np.ndarray, donor: np.ndarray, cols: slice, rows: slice = slice(None)) -> np.ndarray:
    """`base` with `donor`'s columns `cols` over the samples `rows`."""
    out = base.copy()
    k = min(len(base), len(donor))
    rows = slice(*rows.indices(k))
    out[rows, cols] = donor[rows, cols]
    return out


def true_pressure_counts(physical: dict, truth: dict) -> np.ndarray:
    """The ADC counts each pressure channel would read without noise (unrounded)."""
    n = int(physical["ropes"])
    p = np.asarray(truth["p_tap_Pa"], float)
    out = np.zeros((len(p), n))
    for i, ch in enumerate(physical["pressure_channels"]):
        lo, hi = ch["range_Pa"]
        out[:, i] = ch["counts_4mA"] + (p[:, i] - lo) / (hi - lo) * (ch["counts_20mA"] - ch["counts_4mA"])
    return out


def count_step_pa(physical: dict) -> float:
    """Pressure per ADC count of the coarsest pressure channel (Pa)."""
    return max((ch["range_Pa"][1] - ch["range_Pa"][0]) / (ch["counts_20mA"] - ch["counts_4mA"])
               for ch in physical["pressure_channels"])


def scaled_pressure_noise(wind: Wind, scale: float) -> tuple[np.ndarray, dict]:
    """Records and config of `wind` with its pressure noise scaled by `scale` around the
    true tap pressure, rounded to counts as the ADC does; the config's pressure noise
    scaled to match (the ADC's rounding, step/sqrt(12), stays). ValueError if a pressure
    channel ever reads a NAMUR fault (a fault the scaling would not keep).

    The noise before the rounding is taken as uniform within its count (a draw seeded by
    the wind's seed): scaling the rounded counts themselves would round a small change
    away (x0.95 kept 99 % of the noise)."""
    n = int(wind.physical["ropes"])
    clean = true_pressure_counts(wind.physical, wind.truth)
    counts = wind.records[:, :n].astype(float)
    for i, ch in enumerate(wind.physical["pressure_channels"]):
        lo, hi = namur_limits(ch["counts_4mA"], ch["counts_20mA"])
        if counts[:, i].min() < lo or counts[:, i].max() > hi:
            raise ValueError(f"seed {wind.seed}: pressure channel {i + 1} reads a loop fault; not scaled")
    recs = wind.records.copy()
    if scale != 1.0:
        within = np.random.default_rng(wind.seed).uniform(-0.5, 0.5, counts.shape)
        recs[:, :n] = np.rint(clean + scale * (counts + within - clean)).astype(recs.dtype)
    q = count_step_pa(wind.physical) / math.sqrt(12)
    sigma = float(wind.physical["pressure_noise_Pa"])
    physical = {**wind.physical,
                "pressure_noise_Pa": math.sqrt(scale ** 2 * max(sigma ** 2 - q ** 2, 0.0) + q ** 2)}
    return recs, physical


class Smoother:
    """The steady-state Kalman smoother (Rauch-Tung-Striebel) of the median pressure on the
    pressure tracker's own model (nodejson.tracker_gains: a creep at a constant rate plus
    the bounce, its quantised oscillator, the same process and measurement noises)."""

    def __init__(self, physical: dict):
        ph = {**DEFAULTS, **COMPLIANCE_DEFAULTS, **physical}
        fs, n = float(ph["sample_hz"]), int(ph["ropes"])
        tracker = pressure_tracker(ph, fs, n)
        a1, a2 = tracker["a1_q14"] / 16384, tracker["a2_q14"] / 16384
        h = 1.0 / fs
        self.F = np.array(((2.0, -1.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, a1, -a2), (0.0, 0.0, 1.0, 0.0)))
        q = np.diag((float(ph["creep_q_Pa2_s3"]) * h ** 3, 0.0, float(ph["bounce_q_Pa2_s3"]) * h ** 3, 0.0))
        r = (MEDIAN_NOISE[n - 1] * pressure_noise_pa(ph)) ** 2
        H = np.array(((1.0, 0.0, 1.0, 0.0),))
        prior = scipy.linalg.solve_discrete_are(self.F.T, H.T, q, np.array(((r,),)))
        self.K = (prior @ H.T).ravel() / ((H @ prior @ H.T).item() + r)
        post = prior - np.outer(self.K, H @ prior)
        self.C = post @ self.F.T @ np.linalg.inv(prior)
        self.tracker_noise_gain = tracker["noise_gain"]

    def run(self, y: np.ndarray) -> np.ndarray:
        """Creep plus bounce (Pa) over the medians `y` (Pa), started as the tracker starts
        (the creep at the first median, no rate, no bounce)."""
        m = len(y)
        pred, est = np.zeros((m, 4)), np.zeros((m, 4))
        x = np.array((y[0], y[0], 0.0, 0.0))
        for j in range(m):
            p = self.F @ x if j else x
            pred[j] = p
            x = p + self.K * (y[j] - p[0] - p[2])
            est[j] = x
        for j in range(m - 2, -1, -1):
            est[j] += self.C @ (est[j + 1] - pred[j + 1])
        return est[:, 0] + est[:, 2]

    def noise_gain(self, fs: float) -> float:
        """rms of the output per rms of white noise at the input, from the impulse response
        (the tracker's noise_gain, for the smoother)."""
        m = int(40 * fs)
        y = np.zeros(2 * m + 1)
        y[m] = 1.0
        return float(np.sqrt(np.sum(self.run(y) ** 2)))


def smoothed_score(physical: dict, records: np.ndarray, wind: Wind, factor: float) -> dict:
    """score() with the LuGre position from the smoother of the whole wind's median
    instead of the tracker, and the plays and the rest threshold scaled by its noise
    gain over the tracker's, times `factor`."""
    medians: list = []

    class Medians(reference.PressureTracker):  # the tracker's inputs, as the observer forms them
        def step(self, y):
            medians.append(y)
            return super().step(y)

    reference.compensate(physical, records, tracker_class=Medians)
    smoother = Smoother(physical)
    out: list[float] = []
    for healthy, stretch in itertools.groupby(medians, key=lambda y: y is not None):
        stretch = list(stretch)  # each stretch with a median smoothed on its own; without, the last estimate held
        out.extend(smoother.run(np.array(stretch, float)).tolist() if healthy
                   else [out[-1] if out else 0.0] * len(stretch))
    smoothed = iter(out)

    class SmoothedTracker:   # the smoother's estimate, sample by sample, as the tracker's
        def __init__(self, tr):
            self.tr = tr

        def step(self, y):
            if self.tr is None:
                return 0.0
            return min(max(next(smoothed), -reference.P_L_MAX_PA), reference.P_L_MAX_PA)

    f = factor * smoother.noise_gain(float(physical["sample_hz"])) / smoother.tracker_noise_gain
    ph = {**DEFAULTS, **COMPLIANCE_DEFAULTS, **physical}
    scaled = {**physical, **{key: f * float(ph[key]) for key in ("friction_play_sigmas", "rest_sigmas",
                                                                  "rest_play_sigmas")}}
    return score(scaled, records, wind, SmoothedTracker)


def stretches(wind: Wind) -> list[tuple[str, slice]]:
    """The wind cut at the final stop, 4 s after it, and the start of the scored rest."""
    hz = wind.hz
    moving = np.flatnonzero(np.abs(np.asarray(wind.truth["wheel_speed_m_s"], float)) > 1e-3)
    if not moving.size:
        return [("the whole wind", slice(None))]
    stop = int(moving[-1]) + 1
    settle = min(stop + 4 * hz, len(wind.records))
    truth_n = np.asarray(wind.truth["tension_N"], float)
    rated = float(wind.physical["rated_rope_tension_N"])
    from ropemon.lab.evaluate import scoring_masks

    phase, excluded, steady, payload = scoring_masks(wind.truth, truth_n, hz, rated,
                                                     float(wind.physical["hall_marks_m"][-1]))
    rest = M.pithead_rest(phase, excluded, steady)
    empty = rest & (payload == 0.0)
    scored = np.flatnonzero(empty if empty.any() else rest)
    begin = max(int(scored[0]), settle) if scored.size else settle
    cuts = [("until the final stop", slice(0, stop)),
            ("the 4 s after the final stop", slice(stop, settle)),
            ("then until the scored rest", slice(settle, begin)),
            ("the scored rest", slice(begin, None))]
    return [(label, s) for label, s in cuts if (s.stop is None or s.stop > s.start)]


def summary(values: list[float]) -> tuple[int, str]:
    """(seeds within the target, the table cells: within, mean, sd, range)."""
    within = sum(abs(v) <= pithead_target_pct() for v in values)
    return within, (f"{within} of {len(values)} | {statistics.mean(values):+.2f} | "
                    f"{statistics.pstdev(values):.2f} | {min(values):+.2f} / {max(values):+.2f}")


def experiments(winds: list[Wind], scales: list[float], sets: list[tuple[str, list]],
                smoothers: list[float] = (), drifts: list[float] = ()):
    """(label, [(seed, score), ...]) per experiment; (label, reason) for a `--scale` whose
    transmitters the config refuses (and for its `--set` rows the config refuses too)."""
    base = winds[0]
    n = int(base.physical["ropes"])
    yield "as evaluated", [(w.seed, score(w.physical, w.records, w)) for w in winds]
    yield f"seed-{base.seed} config", [(w.seed, score(base.physical, w.records, w)) for w in winds]
    yield "pressure noise only", [(w.seed, score(base.physical, spliced(base.records, w.records, slice(0, n)), base))
                                  for w in winds]
    yield "displacement noise only", [(w.seed, score(base.physical,
                                                     spliced(base.records, w.records, slice(n, 2 * n)), base))
                                      for w in winds]
    levels = {a: [scaled_pressure_noise(w, a) for w in winds] for a in (*scales, *drifts)}
    refused = {}  # scale -> why the config refuses a transmitter of that noise
    for a in scales:
        try:
            rows = [(w.seed, score(ph, recs, w)) for w, (recs, ph) in zip(winds, levels[a])]
        except ValueError as e:  # e.g. too quiet for the node's pressure tracker
            refused[a] = str(e)
            rows = str(e)
        yield f"pressure noise x{a:g}", rows
    for a in drifts:  # the records of x a, the config as commissioned
        yield (f"pressure noise x{a:g} after commissioning",
               [(w.seed, score(w.physical, recs, w)) for w, (recs, _) in zip(winds, levels[a])])
    for f in smoothers:
        yield f"smoother, plays x{f:g}", [(w.seed, smoothed_score(w.physical, w.records, w, f)) for w in winds]
    if not sets:
        return
    keys = [k for k, _ in sets]
    for combo in itertools.product(*(v for _, v in sets)):
        change = dict(zip(keys, combo))
        label = " ".join(f"{k}={json.dumps(v)}" for k, v in change.items())
        as_evaluated = [(w.records, w.physical) for w in winds]
        runs = [(label, as_evaluated, None)]
        runs += [(f"pressure noise x{a:g}, {label}", levels[a], a) for a in scales]
        runs += [(f"pressure noise x{a:g} after commissioning, {label}",
                  [(recs, w.physical) for w, (recs, _) in zip(winds, levels[a])], None) for a in drifts]
        for name, inputs, scale in runs:
            try:
                rows = [(w.seed, score({**ph, **change}, recs, w)) for w, (recs, ph) in zip(winds, inputs)]
            except ValueError as e:
                if scale in refused:  # refused without the setting too: the scale's transmitters
                    yield name, str(e)
                    continue
                raise SystemExit(f"--set {label}: {e}") from None  # the setting: say which and why
            yield name, rows


def scenario_table(out: Path, scenario: str, seeds: list[int] | None, scales: list[float],
                   sets: list[tuple[str, list]], window_seed: int | None,
                   smoothers: list[float] = (), drifts: list[float] = ()) -> dict[str, tuple[int, int, float]]:
    """Print one scenario's tables; (seeds within the target, seeds, worst RMS) per experiment."""
    if seeds is None:
        seeds = sorted(int(p.name.split("-", 1)[1]) for p in out.glob("seed-*")
                       if (p / "runs" / scenario).is_dir())
    if not seeds:
        raise SystemExit(f"{out}: no seed-N/runs/{scenario}; run `ropemon study seed-spread --out {out}` first")
    winds = [load(out, scenario, s) for s in seeds]
    print(f"## {scenario}: `lugre-p+loss` pithead total over seeds {', '.join(map(str, seeds))}\n")
    print(f"| experiment | within {pithead_target_pct()} % | mean % | sd % | min / max % | rope RMS % (worst) "
          "| per seed % |")
    print("|---|---:|---:|---:|---:|---:|---|")
    own: dict[int, float] = {}
    bases = set()
    tally = {}
    for label, rows in experiments(winds, scales, sets, smoothers, drifts):
        if isinstance(rows, str):  # the config refuses this experiment's transmitters
            tally[label] = (0, 0, 0.0)
            print(f"| {label} | config refused: {rows} | | | | | |", flush=True)
            continue
        vals = [r["pithead"] for _, r in rows]
        bases.update(r["basis"] for _, r in rows)
        if label == "as evaluated":
            own = {s: r["pithead"] for s, r in rows}
        rms = max(r["rms"] for _, r in rows)
        within, cells = summary(vals)
        tally[label] = (within, len(vals), rms)
        per = ", ".join(f"{v:+.2f}" for v in vals)
        print(f"| {label} | {cells} | {rms:.2f} | {per} |", flush=True)
    print(f"\n(basis: {', '.join(sorted(bases))} rest)")
    base = winds[0]
    ws = window_seed
    if ws is None and len(winds) > 1:
        ws = max(seeds[1:], key=lambda s: abs(own[s] - own[base.seed]))
    if ws is not None and ws != base.seed:
        donor = next((w for w in winds if w.seed == ws), None)
        if donor is None:
            raise SystemExit(f"--window-seed {ws}: not among the seeds")
        n = int(base.physical["ropes"])
        ref = own[base.seed]
        whole = score(base.physical, spliced(base.records, donor.records, slice(0, n)), base)["pithead"]
        print(f"\nSeed {ws}'s pressure noise in seed {base.seed}'s wind ({ref:+.2f} %), one stretch at a time "
              f"(all of it: {whole:+.2f} %, {whole - ref:+.2f}):\n")
        print("| stretch | from s | to s | pithead % | change % |")
        print("|---|---:|---:|---:|---:|")
        for label, rows in stretches(base):
            v = score(base.physical, spliced(base.records, donor.records, slice(0, n), rows), base)["pithead"]
            lo, hi, _ = rows.indices(len(base.records))
            print(f"| {label} | {lo / base.hz:.1f} | {hi / base.hz:.1f} | {v:+.2f} | {v - ref:+.2f} |")
    print()
    return tally


def summary_table(tallies: dict[str, dict[str, tuple[int, int, float]]]) -> list[str]:
    """Markdown lines: per experiment, the seed-scenarios within the target over all scenarios."""
    names = list(tallies)
    lines = [f"## All {len(names)} scenarios: seed-scenarios within {pithead_target_pct()} %", "",
             "| experiment | within | " + " | ".join(names) + " | rope RMS % (worst) |",
             "|---|---:|" + "---:|" * len(names) + "---:|"]
    for label in tallies[names[0]]:
        cells = [tallies[n][label] for n in names]
        lines.append(f"| {label} | {sum(c[0] for c in cells)} of {sum(c[1] for c in cells)} | "
                     + " | ".join(str(c[0]) for c in cells) + f" | {max(c[2] for c in cells):.2f} |")
    return lines


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("out", type=Path, help="`ropemon study seed-spread`'s --out directory")
    p.add_argument("scenarios", nargs="+", metavar="SCENARIO")
    p.add_argument("--seeds", default=None, help="e.g. 1-10 (default: every seed-N under OUT); the first is the base")
    p.add_argument("--scale", default="0,0.5", help="pressure noise scales, comma-separated ('' for none)")
    p.add_argument("--drift", default="", metavar="A,...",
                   help="pressure noise scales with the config as commissioned (comma-separated)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=V1,V2",
                   help="a setting of `physical` and its values (JSON); repeat for a grid; "
                        "run as evaluated, at each --scale and at each --drift")
    p.add_argument("--smoother", default="", metavar="F,...",
                   help="the whole wind's Kalman smoother for the tracker, its plays x F (comma-separated)")
    p.add_argument("--window-seed", type=int, default=None)


def run(args: argparse.Namespace) -> int:
    seeds = seed_range(args.seeds) if args.seeds else None
    scales = [float(v) for v in args.scale.split(",") if v.strip()]
    sets = parse_set(args.set)
    smoothers = [float(v) for v in args.smoother.split(",") if v.strip()]
    drifts = [float(v) for v in args.drift.split(",") if v.strip()]
    tallies = {name: scenario_table(args.out, name, seeds, scales, sets, args.window_seed, smoothers, drifts)
               for name in args.scenarios}
    if len(tallies) > 1:
        print("\n".join(summary_table(tallies)))
    return 0
