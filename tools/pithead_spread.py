"""Where the pithead total's seed-to-seed spread comes from, and what would narrow it.

`tools/seed_spread.py` shows that the full compensation's pithead total moves with
the noise seed (notes/accuracy-research.md, "Seed spread"). This takes its work directory
(OUT/seed-N/runs/SCENARIO: each seed's simulated wind, the truth, and the node
config that seed's commissioning made) and reruns the float reference
(`lugre-p+loss`) on recombined inputs, one experiment per row:

- as evaluated: each seed's wind with its own config (seed_spread's figure);
- seed-1 config: each seed's wind with the first seed's config (its friction
  fit, k, pressure noise and bounce; the first of `--seeds`, seed 1 by
  default): what the calibration's draw adds;
- pressure noise only / displacement noise only: the first seed's wind with
  seed N's pressure (or displacement) channels;
- pressure noise x A (`--scale A,...`): each seed's wind with its pressure noise
  scaled by A around the true tap pressure (0: a noise-free transmitter on the
  same ADC), the config's `pressure_noise_Pa` scaled to match: transmitters of
  that noise, commissioned with it;
- pressure noise x A after commissioning (`--drift A,...`): the same winds with
  the config as commissioned: the transmitters' noise changed since;
- `--set KEY=V1,V2 ...`: each combination of settings of the config's
  `physical` section (JSON values), as tools/observer_sensitivity.py changes them,
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
0.3 % per experiment.

The figure is the pithead total error, empty cage (the paper's case), or the
arrival rest where the scenario has no empty one, in % of the true total.

    .venv/bin/python tools/seed_spread.py paper-field-trip payload-12t --seeds 1-10 --out out/seed-spread
    .venv/bin/python tools/pithead_spread.py out/seed-spread paper-field-trip payload-12t --scale 0,0.5
    .venv/bin/python tools/pithead_spread.py out/seed-spread payload-12t --scale "" \\
        --set creep_q_Pa2_s3=3e8,3e9 --set friction_play_sigmas=0.8,1.45
    .venv/bin/python tools/pithead_spread.py out/seed-spread paper-field-trip --scale 0.5 \\
        --set friction_play_sigmas=1.45,1.6 --drift 0.9,1.1
"""
from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import math
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.linalg

from ropemon.lab import evaluate as EV
from ropemon.lab import metrics as M
from ropemon.commission import reference
from ropemon.commission.nodeconfig import (COMPLIANCE_DEFAULTS, DEFAULTS, MEDIAN_NOISE, namur_limits, pressure_noise_pa,
                                pressure_tracker)

sys.path.insert(0, str(Path(__file__).resolve().parent))  # its sibling, however this was loaded
from seed_spread import PITHEAD_PCT as TARGET_PCT  # noqa: E402  (issue 6: within 0.3 %)
from seed_spread import seed_range  # noqa: E402


@dataclass
class Wind:
    """One seed's run of a scenario: records, truth and the config its commissioning made."""
    seed: int
    records: np.ndarray
    truth: dict
    physical: dict
    hz: int


def load(out: Path, scenario: str, seed: int) -> Wind:
    run = out / f"seed-{seed}" / "runs" / scenario
    _ropes, hz, recs = reference.read_rsens(run / "sim" / "sensors.rsens")
    with np.load(run / "sim" / "truth.npz") as z:
        truth = {k: z[k] for k in z.files}
    physical = json.loads((run / "node-evaluated.json").read_text())["physical"]
    k = min(len(recs), len(truth["tension_N"]))
    return Wind(seed, recs[:k], {key: v[:k] if np.ndim(v) else v for key, v in truth.items()}, physical, hz)


def score(physical: dict, records: np.ndarray, wind: Wind) -> dict:
    """The float reference's pithead total (%), its basis, and the rope RMS (% of rated)."""
    truth_n = np.asarray(wind.truth["tension_N"], float)[:len(records)]
    rated = float(physical["rated_rope_tension_N"])
    phase, excluded, steady, payload = EV.scoring_masks(wind.truth, truth_n, wind.hz, rated,
                                                        float(physical["hall_marks_m"][-1]))
    est = reference.compensate(physical, records).tension_n
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
    pressure tracker's own model (nodeconfig.tracker_gains: a creep at a constant rate plus
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


@contextlib.contextmanager
def _pressure_tracker(cls):
    """reference.compensate with `cls` in place of the node's pressure tracker."""
    saved = reference.PressureTracker
    reference.PressureTracker = cls
    try:
        yield
    finally:
        reference.PressureTracker = saved


def smoothed_score(physical: dict, records: np.ndarray, wind: Wind, factor: float) -> dict:
    """score() with the LuGre position from the smoother of the whole wind's median
    instead of the tracker, and the plays and the rest threshold scaled by its noise
    gain over the tracker's, times `factor`."""
    medians: list = []

    class Medians(reference.PressureTracker):  # the tracker's inputs, as the observer forms them
        def step(self, y):
            medians.append(y)
            return super().step(y)

    with _pressure_tracker(Medians):
        reference.compensate(physical, records)
    smoother = Smoother(physical)
    out: list[float] = []
    for healthy, run in itertools.groupby(medians, key=lambda y: y is not None):
        run = list(run)  # each stretch with a median smoothed on its own; without, the last estimate held
        out.extend(smoother.run(np.array(run, float)).tolist() if healthy else [out[-1] if out else 0.0] * len(run))
    replay = iter(out)

    class Replay:
        def __init__(self, tr):
            self.tr = tr

        def step(self, y):
            if self.tr is None:
                return 0.0
            return min(max(next(replay), -reference.P_L_MAX_PA), reference.P_L_MAX_PA)

    f = factor * smoother.noise_gain(float(physical["sample_hz"])) / smoother.tracker_noise_gain
    ph = {**DEFAULTS, **COMPLIANCE_DEFAULTS, **physical}
    scaled = {**physical, **{key: f * float(ph[key]) for key in ("friction_play_sigmas", "rest_sigmas",
                                                                  "rest_play_sigmas")}}
    with _pressure_tracker(Replay):
        return score(scaled, records, wind)


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
    phase, excluded, steady, payload = EV.scoring_masks(wind.truth, truth_n, hz, rated,
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
    within = sum(abs(v) <= TARGET_PCT for v in values)
    return within, (f"{within} of {len(values)} | {statistics.mean(values):+.2f} | "
                    f"{statistics.pstdev(values):.2f} | {min(values):+.2f} / {max(values):+.2f}")


def parse_set(items: list[str]) -> list[tuple[str, list]]:
    """['KEY=V1,V2', ...] -> [(KEY, [V1, V2]), ...] with JSON values."""
    out = []
    for item in items:
        key, sep, values = item.partition("=")
        if not sep or not key or not values:
            raise SystemExit(f"--set {item!r}: expected KEY=V1[,V2...]")
        try:
            out.append((key, [json.loads(v) for v in values.split(",")]))
        except json.JSONDecodeError as e:
            raise SystemExit(f"--set {item!r}: {e}") from None
    return out


def experiments(winds: list[Wind], scales: list[float], sets: list[tuple[str, list]],
                smoothers: list[float] = (), drifts: list[float] = ()):
    """(label, [(seed, score), ...]) per experiment."""
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
    for a in scales:
        yield f"pressure noise x{a:g}", [(w.seed, score(ph, recs, w)) for w, (recs, ph) in zip(winds, levels[a])]
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
        runs = [(label, as_evaluated)]
        runs += [(f"pressure noise x{a:g}, {label}", levels[a]) for a in scales]
        runs += [(f"pressure noise x{a:g} after commissioning, {label}",
                  [(recs, w.physical) for w, (recs, _) in zip(winds, levels[a])]) for a in drifts]
        for name, inputs in runs:
            try:
                rows = [(w.seed, score({**ph, **change}, recs, w)) for w, (recs, ph) in zip(winds, inputs)]
            except ValueError as e:  # the config refuses the setting: say which and why
                raise SystemExit(f"--set {label}: {e}") from None
            yield name, rows


def scenario_table(out: Path, scenario: str, seeds: list[int] | None, scales: list[float],
                   sets: list[tuple[str, list]], window_seed: int | None,
                   smoothers: list[float] = (), drifts: list[float] = ()) -> dict[str, tuple[int, int, float]]:
    """Print one scenario's tables; (seeds within the target, seeds, worst RMS) per experiment."""
    if seeds is None:
        seeds = sorted(int(p.name.split("-", 1)[1]) for p in out.glob("seed-*")
                       if (p / "runs" / scenario).is_dir())
    if not seeds:
        raise SystemExit(f"{out}: no seed-N/runs/{scenario}; run tools/seed_spread.py --out {out} first")
    winds = [load(out, scenario, s) for s in seeds]
    print(f"## {scenario}: `lugre-p+loss` pithead total over seeds {', '.join(map(str, seeds))}\n")
    print(f"| experiment | within {TARGET_PCT} % | mean % | sd % | min / max % | rope RMS % (worst) | per seed % |")
    print("|---|---:|---:|---:|---:|---:|---|")
    own: dict[int, float] = {}
    bases = set()
    tally = {}
    for label, rows in experiments(winds, scales, sets, smoothers, drifts):
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
    lines = [f"## All {len(names)} scenarios: seed-scenarios within {TARGET_PCT} %", "",
             "| experiment | within | " + " | ".join(names) + " | rope RMS % (worst) |",
             "|---|---:|" + "---:|" * len(names) + "---:|"]
    for label in tallies[names[0]]:
        cells = [tallies[n][label] for n in names]
        lines.append(f"| {label} | {sum(c[0] for c in cells)} of {sum(c[1] for c in cells)} | "
                     + " | ".join(str(c[0]) for c in cells) + f" | {max(c[2] for c in cells):.2f} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path, help="tools/seed_spread.py's --out directory")
    ap.add_argument("scenarios", nargs="+")
    ap.add_argument("--seeds", default=None, help="e.g. 1-10 (default: every seed-N under OUT); the first is the base")
    ap.add_argument("--scale", default="0,0.5", help="pressure noise scales, comma-separated ('' for none)")
    ap.add_argument("--drift", default="", metavar="A,...",
                    help="pressure noise scales with the config as commissioned (comma-separated)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=V1,V2",
                    help="a setting of `physical` and its values (JSON); repeat for a grid; "
                         "run as evaluated, at each --scale and at each --drift")
    ap.add_argument("--smoother", default="", metavar="F,...",
                    help="the whole wind's Kalman smoother for the tracker, its plays x F (comma-separated)")
    ap.add_argument("--window-seed", type=int, default=None)
    a = ap.parse_args(argv)
    seeds = seed_range(a.seeds) if a.seeds else None
    scales = [float(v) for v in a.scale.split(",") if v.strip()]
    sets = parse_set(a.set)
    smoothers = [float(v) for v in a.smoother.split(",") if v.strip()]
    drifts = [float(v) for v in a.drift.split(",") if v.strip()]
    tallies = {name: scenario_table(a.out, name, seeds, scales, sets, a.window_seed, smoothers, drifts)
               for name in a.scenarios}
    if len(tallies) > 1:
        print("\n".join(summary_table(tallies)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
