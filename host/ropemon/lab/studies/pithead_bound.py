"""`ropemon study pithead-bound RUN [RUN ...] [--scale 1,0.5]`: how closely any estimator could
read the pithead total through the pressure noise (docs/accuracy.md, "Transmitter noise").

A resting seal relaxes by the path the cage's bounce makes its piston travel, and the
node reads that path from the pressure channels, through their noise (`ropemon study
pithead-spread`). This study bounds the spread that noise leaves, for an
estimator far better informed than the node: it knows the plant's seal law with its true
parameters, the pistons' true creep, and the bounce's shape (frequency, decay, phase),
and has only to read how large the bounce is, one unknown scale per episode after the
final stop (split where the payload starts or stops changing: the arrival rest, the
unloading, the empty rest).

Per episode, from a run directory (`ropemon.lab.rundir`; the simulator's output is
enough, the config is the simulator's):
- the bounce is the part above 1 Hz (zero-phase Butterworth) of the mean tap pressure,
  and of each piston's position, over the episode;
- the Cramer-Rao bound on its scale from the n pressure channels and the n
  displacement channels, each with the noise its records really carry (records less
  the true tap pressure or piston position, in counts): 1 / sd**2 = sum(bounce_p**2) /
  sigma_p**2 + sum_i sum(bounce_x_i**2) / sigma_x_i**2, where sigma_p is the noise of
  the pressure channels' mean (they read one joined cavity pressure at rest); the
  displacement channels add well under 1 % to it;
- the scored pithead total's change when the episode's bounce is scaled by 1 + sd and
  1 - sd (half the difference): the plant's own seal law (`ropemon.lab.plant.friction`)
  re-run over the pistons' true path from before the stop, exact per sample for the
  velocity held over it. `check` is how far that re-run of the true path is from the
  truth's friction (it must be small against the changes).

The episodes' noise is independent, so their sds add in squares. An unbiased estimator
cannot do better; a biased one only by knowing the bounce before the wind shows it.
An episode whose bounce is less than twice its own sd is left out (its effect is not
linear in the scale), which only lowers the bound. `--scale` multiplies the noise.

    ropemon study pithead-bound out/evaluate/runs/paper-field-trip out/evaluate/runs/payload-0t \\
        out/evaluate/runs/payload-12t --scale 1,0.5
"""
from __future__ import annotations

import argparse
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import butter, sosfiltfilt
from scipy.stats import norm

from ropemon.lab import metrics as M
from ropemon.lab.plant.friction import LuGre, from_table
from ropemon.lab.rundir import RunDir
from ropemon.lab.studies import pithead_target_pct
from ropemon.lab.studies.pithead_spread import count_step_pa, true_pressure_counts

BOUNCE_ABOVE_HZ = 1.0   # the bounce: what lies above this (the pistons' creep lies below)
MIN_SNR = 2.0           # an episode counts when its bounce is this many sds of its scale


@dataclass
class PitheadRest:
    """A run's final stop and pithead rest, what the bound needs of it."""
    name: str
    hz: int
    truth: Mapping           # the truth arrays (rundir.Truth), over the samples with records
    law: LuGre
    stop: int                # first sample after the hoist's final motion
    scored: np.ndarray       # bool per sample: the pithead rest the total is scored over
    episodes: list[slice]    # from the stop to the end of the scored rest
    channel_noise_pa: np.ndarray  # rms noise of each pressure channel's records
    channel_noise_m: np.ndarray   # and of each displacement channel's


def load(run: RunDir) -> PitheadRest:
    meta = run.meta
    fr = meta["hidden"]["plant"]["friction"]
    law = from_table(fr, "plant.friction")
    if not isinstance(law, LuGre):
        raise SystemExit(f"{run.path}: the plant's seal is {law.name}, not LuGre: no seal state to bound")
    hz, recs = run.sample_hz, run.records
    k = run.length
    truth = run.truth.cut(k)
    physical = meta["node_physical"]
    n = int(physical["ropes"])
    noise = (recs[:k, :n] - true_pressure_counts(physical, truth)).std(axis=0) * count_step_pa(physical)
    x_noise = np.empty(n)
    for i, ch in enumerate(physical["displacement_channels"]):
        lo, hi = ch["range_m"]
        per_count = (hi - lo) / (ch["counts_hi"] - ch["counts_lo"])
        x_noise[i] = (recs[:k, n + i] - ch["counts_lo"]
                      - (truth["piston_x_m"][:, i] - lo) / per_count).std() * per_count
    sc = run.scoring(physical)
    phase, excluded, steady, payload = sc.phase, sc.excluded, sc.steady, sc.payload_kg
    rest = M.pithead_rest(phase, excluded, steady)
    empty = rest & (payload == 0.0)
    scored = empty if empty.any() else rest
    moving = np.flatnonzero(np.abs(truth["wheel_speed_m_s"]) > 1e-3)
    if not scored.any() or not moving.size:
        raise SystemExit(f"{run.path}: no pithead rest after a wind to bound")
    stop, end = int(moving[-1]) + 1, int(np.flatnonzero(scored)[-1]) + 1
    # cut where the payload starts or stops changing
    changing = np.r_[False, np.diff(payload) != 0.0]
    flips = [i for i in range(stop + 1, end) if changing[i] != changing[i - 1]]
    edges = [stop, *flips, end]
    return PitheadRest(run.path.name, hz, truth, law, stop, scored,
                       [slice(a, b) for a, b in zip(edges, edges[1:])], noise, x_noise)


def seal_friction(law: LuGre, x: np.ndarray, p: np.ndarray, z0: np.ndarray, hz: int) -> np.ndarray:
    """The law's friction per sample over the pistons' path `x` (samples, ropes), from the
    state z0 at its first sample: each sample's velocity held over it, where the state's
    equation is linear, dz/dt = v + zd_z z, and its exact solution is taken."""
    h = 1.0 / hz
    z = np.array(z0, float)
    out = np.empty_like(x)
    v = np.vstack([np.diff(x, axis=0) * hz, np.zeros((1, x.shape[1]))])
    for i in range(len(x)):
        f = law.evaluate(v[i], z, p[i])
        out[i] = f.F
        a = -f.zd_z
        moving = a > 0.0
        z_ss = np.where(moving, v[i] / np.where(moving, a, 1.0), 0.0)
        z = np.where(moving, z_ss + (z - z_ss) * np.exp(-a * h), z)
    return out


@dataclass
class Episode:
    span: slice
    amplitude_um: float     # the pistons' bounce, rms * sqrt(2)
    scale_sd: float         # Cramer-Rao sd of its scale
    total_sd_pct: float     # the scored total's change for a scale off by one sd (nan: left out)


def bound(rest: PitheadRest, noise_scale: float = 1.0) -> tuple[list[Episode], float]:
    """The episodes and the re-run's check (largest |friction - truth's| over the scored
    rest, in % of the true total there)."""
    t = rest.truth
    sos = butter(2, BOUNCE_ABOVE_HZ, "highpass", fs=rest.hz, output="sos")
    x, p = np.asarray(t["piston_x_m"], float), np.asarray(t["p_cav_Pa"], float)
    bounce_x = sosfiltfilt(sos, x, axis=0)
    bounce_p = sosfiltfilt(sos, np.asarray(t["p_tap_Pa"], float).mean(axis=1))
    start = max(0, rest.stop - rest.hz)             # a second before the stop: the state is the truth's
    end = int(np.flatnonzero(rest.scored)[-1]) + 1
    scored = rest.scored[start:end]
    total = float(np.asarray(t["tension_N"], float)[start:end][scored].sum(axis=1).mean())
    z0 = np.asarray(t["z_m"], float)[start]

    def total_friction(path: np.ndarray) -> float:
        f = seal_friction(rest.law, path[start:end], p[start:end], z0, rest.hz)
        return float(f[scored].sum(axis=1).mean())

    rerun = seal_friction(rest.law, x[start:end], p[start:end], z0, rest.hz)
    check = float(np.abs(rerun[scored] - np.asarray(t["friction_N"], float)[start:end][scored]).sum(axis=1).max())
    out = []
    for span in rest.episodes:
        sd = scale_sd(bounce_p[span], rest.channel_noise_pa * noise_scale,
                      bounce_x[span], rest.channel_noise_m * noise_scale)
        amp = float(np.sqrt(2 * (bounce_x[span] ** 2).mean())) * 1e6
        effect = math.nan
        if sd * MIN_SNR <= 1.0:
            w = np.zeros((len(x), 1))
            w[span] = 1.0
            up, down = (total_friction(x + s * sd * bounce_x * w) for s in (1.0, -1.0))
            # the tension is p A - F: more friction reads the total lower
            effect = -(up - down) / 2 / total * 100
        out.append(Episode(span, amp, sd, effect))
    return out, check / total * 100


def scale_sd(bounce_pa: np.ndarray, channel_noise_pa: np.ndarray,
             bounce_m: np.ndarray | None = None, channel_noise_m: np.ndarray | None = None) -> float:
    """Cramer-Rao sd of one scale of known waveforms: `bounce_pa` (Pa per sample) read by
    every pressure channel, whose independent white noises have these rms values (their
    mean is the best reading), and optionally `bounce_m` (samples, channels) read each by
    its own displacement channel."""
    noise = np.asarray(channel_noise_pa, float)
    info = float((np.asarray(bounce_pa, float) ** 2).sum()) * len(noise) ** 2 / float((noise ** 2).sum())
    if bounce_m is not None:
        info += float(((np.asarray(bounce_m, float) / np.asarray(channel_noise_m, float)) ** 2).sum())
    return 1.0 / math.sqrt(info) if info > 0 else math.inf


def combined_sd(episodes: list[Episode]) -> float:
    return math.sqrt(sum(e.total_sd_pct ** 2 for e in episodes if math.isfinite(e.total_sd_pct)))


def outside(sd: float, limit: float | None = None) -> float:
    """The share of winds beyond +-limit (default: the pithead target) for a Gaussian error
    of this sd and no bias."""
    limit = pithead_target_pct() if limit is None else limit
    return 2 * norm.sf(limit / sd) if sd > 0 else 0.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("runs", nargs="+", type=Path, metavar="RUN", help="run directories (out/evaluate/runs/SCENARIO)")
    p.add_argument("--scale", default="1", help="noise scales, comma-separated (default 1)")


def run(args: argparse.Namespace) -> int:
    scales = [float(s) for s in args.scale.split(",")]
    rows = []
    target = pithead_target_pct()
    for path in args.runs:
        rest = load(RunDir(path))
        noise = ", ".join(f"{v / 1e3:.2f}" for v in rest.channel_noise_pa)
        x_noise = ", ".join(f"{v * 1e6:.1f}" for v in rest.channel_noise_m)
        print(f"{rest.name}: final stop at {rest.stop / rest.hz:.2f} s; noise of the pressure channels "
              f"{noise} kPa rms, of the displacement channels {x_noise} um rms")
        for scale in scales:
            eps, check = bound(rest, scale)
            for e in eps:
                effect = "left out" if not math.isfinite(e.total_sd_pct) else f"{e.total_sd_pct:.3f} %"
                print(f"  x{scale:g} {e.span.start / rest.hz:7.2f}-{e.span.stop / rest.hz:7.2f} s: bounce "
                      f"{e.amplitude_um:.3f} um, scale sd {e.scale_sd:.3f}, total {effect}")
            sd = combined_sd(eps)
            print(f"  x{scale:g} bound: sd {sd:.3f} % (re-run check {check:.4f} %), "
                  f"{outside(sd) * 100:.1f} % of winds beyond {target} %")
            rows.append(f"| {rest.name} | x{scale:g} | {sd:.3f} | {outside(sd) * 100:.1f} % |")
    print()
    print(f"| scenario | noise | bound on the sd of the pithead total, % | winds beyond {target} % at least |")
    print("|---|---:|---:|---:|")
    print("\n".join(rows))
    return 0
