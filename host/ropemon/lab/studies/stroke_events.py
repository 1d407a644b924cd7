"""`ropemon study stroke-events RUN [--until S]`: the balancing strokes the node and the float
reference take, side by side.

Runs a run directory's sensor stream (`ropemon.lab.rundir`, as `ropemon evaluate` left it)
through the node's plain kernel under CPython (`ropenode.kernel`, bit-identical to the
viper one the node runs) and through `ropemon.commission.reference`, with the commissioned
config (node-evaluated.json), and prints every start and end of a stroke of each: time,
rope, and each rope's e (the low-pass of x_f - x_h, um) as the decision compared it,
marking those the other does not take at the same sample: where the firmware and its float
reference decide apart (docs/accuracy.md). Then the same against the reference that
follows the node's decisions where the two decide apart by rounding (reference.Follow).
Slow: the plain kernel runs some thousand samples a second under CPython.
"""
from __future__ import annotations

import argparse
import array
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ropemon.commission import reference
from ropemon.firmware import node_module
from ropemon.lab.rundir import RunDir


@dataclass
class NodeTrace:
    """The node after each sample: its stroke tracking (`tracking`[k]: every rope healthy,
    started and warmed up; `state`[k, 3] of (mode, direction, count); e[k, N] in m and
    cl[k] in m per sample as its stroke decision compared them: reference.Follow's),
    tension[k, N] in N and good[k, N]."""

    tracking: np.ndarray
    state: np.ndarray
    e: np.ndarray
    cl: np.ndarray
    tension: np.ndarray
    good: np.ndarray

    def follow(self) -> reference.Follow:
        """A Follow of this trace (its own copies: a test may alter them)."""
        return reference.Follow(self.tracking.copy(), self.state.copy(), self.e.copy(), self.cl.copy())


def node_trace(doc: dict, recs) -> NodeTrace:
    """Run records[k, 2N+4] through the node's plain kernel with config `doc`. Where a stroke
    starts or ends the node overwrites e after deciding: that sample runs again on a copy of
    the state that keeps e as the mode is written."""
    config = node_module("config")
    kernel = node_module("kernel")
    node = node_module("node").Node(config.parse(doc), step=kernel.step)
    S, P = node.S, node.P
    n = int(doc["physical"]["ropes"])
    k = recs.shape[0]
    rec = array.array("H", [0] * recs.shape[1])
    tracking = np.zeros(k, bool)
    state = np.zeros((k, 3), np.int64)
    e = np.zeros((k, n), np.int64)
    cl = np.zeros(k, np.int64)
    ten = np.zeros((k, n), np.int64)
    good = np.zeros(k, np.int64)
    E, MODE, WARM = kernel._E, kernel._SMODE, kernel._WARM
    every = (1 << n) - 1
    warm = P[kernel._WARMN]

    class Watch(array.array):
        def __setitem__(self, i, v):
            if i == MODE:
                self.e = self[E:E + n].tolist()
            super().__setitem__(i, v)

    at = (MODE, kernel._SSGN, kernel._SCNT)
    for j, row in enumerate(recs.tolist()):
        rec[:] = array.array("H", row)
        before = S[:]
        node.sample(rec)
        # the kernel's allw: a stroke threshold, every rope healthy now, started before and
        # warmed up before this sample
        tracking[j] = (P[kernel._STH] != 0 and S[kernel.GOOD] & every == every
                       and before[kernel._STARTED] & every == every
                       and min(before[WARM:WARM + n]) >= warm)
        state[j] = [S[a] for a in at]
        e[j] = S[E:E + n]
        if S[MODE] != before[MODE]:
            w = Watch(before.typecode, before)
            kernel.step(w, P, rec, n)
            if w != S:
                raise RuntimeError(f"sample {j}: the kernel's step is not a function of its arguments")
            e[j] = w.e
        cl[j] = S[kernel._CL]
        ten[j] = node.rope(kernel.TENSION_N)
        good[j] = S[kernel.GOOD]
    return NodeTrace(tracking, state, e / 256e6, cl / 65536e6, ten.astype(float),
                     (good[:, None] >> np.arange(n)) & 1 == 1)


def node_strokes(doc: dict, recs, trace: NodeTrace | None = None) -> list[tuple[int, int, list[float]]]:
    """(sample, rope or -1, e per rope in um as the decision compared it) at each stroke
    start/end of the node (`trace`: its node_trace, if already run)."""
    tr = trace or node_trace(doc, recs)
    mode = tr.state[:, 0]
    changes = np.flatnonzero(mode != np.concatenate(([0], mode[:-1])))
    return [(int(j), int(mode[j]) - 1, (tr.e[j] * 1e6).tolist()) for j in changes]


def follow_figures(wind: RunDir, samples: int | None = None, trace: NodeTrace | None = None) -> dict:
    """The node against the float reference that follows its stroke decisions where the two
    decide apart by rounding (reference.Follow), over the first `samples` of a run's stream:
    max % of rated over frame-window means of the tensions (in N, before the frame's daN),
    the decisions followed and disputed, and how far apart the two held the values the
    decisions compare near the thresholds (`decision_gaps`: e in um, cl as a share of the
    minimum speed). `trace`: the node's over those samples, if already run."""
    from ropemon.lab import metrics as M

    doc, recs = wind.config, wind.records[:samples]
    ph = doc["physical"]
    tr = trace or node_trace(doc, recs)
    follow = tr.follow()
    inc: dict = {}
    ref = reference.compensate(ph, recs, increments=inc, follow=follow).tension_n
    w = int(ph["sample_hz"]) // int(ph["frame_hz"])
    node = M.window_means(np.where(tr.good, tr.tension, np.nan), w)
    diff = (node - M.window_means(ref, w)) / float(ph["rated_rope_tension_N"]) * 100.0
    both = np.isfinite(diff)
    pp = reference.physical_params(ph)
    gap_e, gap_cl = decision_gaps(tr, inc, pp["stroke_m"], pp["stroke_vmin"])
    return {"max_pct": float(np.max(np.abs(diff[both]))) if both.any() else float("nan"),
            "followed": len(follow.followed), "disputes": len(follow.disputes),
            "e_gap_um": gap_e * 1e6, "cl_gap_of_vmin": gap_cl / pp["stroke_vmin"] if pp["stroke_vmin"] else 0.0}


def decision_gaps(tr: NodeTrace, inc: dict, th: float, vmin: float) -> tuple[float, float]:
    """How far apart node and reference (`increments` of reference.compensate) held e (m)
    and cl (m per sample) where it mattered: at the samples with a rope's |e| within a
    tenth of the threshold, and with |cl| within a tenth of the minimum speed or of zero
    (where no stroke starts or ends: there the node's e after the sample is what it
    compared)."""
    mode = tr.state[:, 0]
    still = mode == np.concatenate(([0], mode[:-1]))
    near = still[:, None] & (np.abs(np.abs(tr.e) - th) <= 0.1 * th)
    gap_e = float(np.max(np.abs(inc["e"] - tr.e)[near])) if near.any() else 0.0
    c = np.abs(tr.cl)
    near = (np.abs(c - vmin) <= 0.1 * vmin) | (c <= 0.1 * vmin)
    gap_cl = float(np.max(np.abs(inc["cl"] - tr.cl)[near])) if near.any() else 0.0
    return gap_e, gap_cl


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", type=Path, metavar="RUN", help="a run directory (out/evaluate/runs/SCENARIO)")
    p.add_argument("--until", type=float, metavar="S", help="stop after this many seconds of the stream")


def run(args: argparse.Namespace) -> int:
    wind = RunDir(args.run)
    doc, hz, recs = wind.config, wind.sample_hz, wind.records
    if args.until is not None:
        recs = recs[: int(args.until * hz)]
    ref: list = []
    reference.compensate(doc["physical"], recs, strokes=ref)
    ref = [(j, r, [v * 1e6 for v in e]) for j, r, e in ref]
    trace = node_trace(doc, recs)
    node = node_strokes(doc, recs, trace)
    keys = {"node": {(j, r) for j, r, _ in node}, "reference": {(j, r) for j, r, _ in ref}}
    rows = sorted([(j, "node", r, e) for j, r, e in node] + [(j, "reference", r, e) for j, r, e in ref])
    print(f"{args.run}: {len(recs)} samples; strokes started: node {sum(r >= 0 for _, r, _ in node)}, "
          f"reference {sum(r >= 0 for _, r, _ in ref)}")
    other = {"node": "reference", "reference": "node"}
    for j, who, r, e in rows:
        alone = "" if (j, r) in keys[other[who]] else f"   <- not the {other[who]}'s"
        what = f"start rope {r + 1}" if r >= 0 else "end"
        print(f"{j / hz:9.3f} s  {who:9s}  {what:12s}  e (um) " + " ".join(f"{v:7.2f}" for v in e) + alone)
    f = follow_figures(wind, len(recs), trace)
    print(f"following the node where the two decide apart by rounding: {f['followed']} decisions followed, "
          f"{f['disputes']} disputed; frames within {f['max_pct']:.4f} % of rated; near the thresholds e "
          f"{f['e_gap_um']:.4f} um and cl {f['cl_gap_of_vmin']:.4f} of the minimum speed apart")
    return 0
