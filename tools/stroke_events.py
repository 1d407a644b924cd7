"""The balancing strokes the node and the float reference take, side by side.

Runs a scenario's sensor stream (as `ropemon evaluate` left it in RUN) through
the node's plain kernel under CPython (`ropenode.kernel`, bit-identical to the
viper one the node runs) and through `ropemon.commission.reference`, with the commissioned
`RUN/node-evaluated.json`, and prints every start and end of a stroke of each:
time, rope, and each rope's e (the low-pass of x_f - x_h, um) as the deciding
sample began, marking those the other does not take at the same sample. Slow:
the plain kernel runs some thousand samples a second under CPython.

    .venv/bin/python tools/stroke_events.py out/evaluate/runs/duty-cycle-50 [--until S]
"""
from __future__ import annotations

import argparse
import array
import json
import sys
from pathlib import Path

from ropemon.commission import reference
from ropemon.firmware import node_module


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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="a scenario's directory under out/evaluate/runs")
    ap.add_argument("--until", type=float, help="stop after this many seconds of the stream")
    a = ap.parse_args(argv)
    doc = json.loads((a.run / "node-evaluated.json").read_text())
    _r, hz, recs = reference.read_rsens(a.run / "sim" / "sensors.rsens")
    if a.until is not None:
        recs = recs[: int(a.until * hz)]
    ref: list = []
    reference.compensate(doc["physical"], recs, strokes=ref)
    ref = [(j, r, [v * 1e6 for v in e]) for j, r, e in ref]
    node = node_strokes(doc, recs)
    keys = {"node": {(j, r) for j, r, _ in node}, "reference": {(j, r) for j, r, _ in ref}}
    rows = sorted([(j, "node", r, e) for j, r, e in node] + [(j, "reference", r, e) for j, r, e in ref])
    print(f"{a.run}: {len(recs)} samples; strokes started: node {sum(r >= 0 for _, r, _ in node)}, "
          f"reference {sum(r >= 0 for _, r, _ in ref)}")
    other = {"node": "reference", "reference": "node"}
    for j, who, r, e in rows:
        alone = "" if (j, r) in keys[other[who]] else f"   <- not the {other[who]}'s"
        what = f"start rope {r + 1}" if r >= 0 else "end"
        print(f"{j / hz:9.3f} s  {who:9s}  {what:12s}  e (um) " + " ".join(f"{v:7.2f}" for v in e) + alone)
    return 0


if __name__ == "__main__":
    sys.exit(main())
