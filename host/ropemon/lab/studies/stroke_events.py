"""`ropemon study stroke-events RUN [--until S]`: the balancing strokes the node and the float
reference take, side by side.

Runs a run directory's sensor stream (`ropemon.lab.rundir`, as `ropemon evaluate` left it)
through the node's plain kernel under CPython (`ropenode.kernel`, bit-identical to the
viper one the node runs) and through `ropemon.commission.reference`, with the commissioned
config (node-evaluated.json), and prints every start and end of a stroke of each: time,
rope, and each rope's e (the low-pass of x_f - x_h, um) as the deciding sample began,
marking those the other does not take at the same sample: where the firmware and its float
reference decide a sample apart (docs/accuracy.md). Slow: the plain kernel runs some
thousand samples a second under CPython.
"""
from __future__ import annotations

import argparse
import array
from pathlib import Path

from ropemon.commission import reference
from ropemon.firmware import node_module
from ropemon.lab.rundir import RunDir


def node_strokes(doc: dict, recs) -> list[tuple[int, int, list[float]]]:
    """(sample, rope or -1, e per rope in um) at each stroke start/end of the node."""
    config = node_module("config")
    kernel = node_module("kernel")
    node = node_module("node").Node(config.parse(doc), step=kernel.step)
    S = node.S
    rec = array.array("H", [0] * recs.shape[1])
    out, mode, n = [], 0, int(doc["physical"]["ropes"])
    for j, row in enumerate(recs.tolist()):
        rec[:] = array.array("H", row)
        e_before = [S[kernel._E + i] / 256 for i in range(n)]
        node.sample(rec)
        if S[kernel._SMODE] != mode:
            mode = S[kernel._SMODE]
            out.append((j, mode - 1, e_before))
    return out


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
    node = node_strokes(doc, recs)
    keys = {"node": {(j, r) for j, r, _ in node}, "reference": {(j, r) for j, r, _ in ref}}
    rows = sorted([(j, "node", r, e) for j, r, e in node] + [(j, "reference", r, e) for j, r, e in ref])
    print(f"{args.run}: {len(recs)} samples; strokes started: node {sum(r >= 0 for _, r, _ in node)}, "
          f"reference {sum(r >= 0 for _, r, _ in ref)}")
    other = {"node": "reference", "reference": "node"}
    for j, who, r, e in rows:
        alone = "" if (j, r) in keys[other[who]] else f"   <- not the {other[who]}'s"
        what = f"start rope {r + 1}" if r >= 0 else "end"
        print(f"{j / hz:9.3f} s  {who:9s}  {what:12s}  e (um) " + " ".join(f"{v:7.2f}" for v in e) + alone)
    return 0
