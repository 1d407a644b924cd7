"""The pistons' creep and path against the node's, over a time window of a run.

A resting seal settles where the creep that loads it balances the back-and-forth
path that relaxes it (notes/accuracy-research.md, "Sensitivity"). For a window [T0, T1] of
a run directory as `ropemon evaluate` left it, this prints per rope:

- creep: the net piston travel (mean of 0.1 s either side of T0 and T1), the
  plant's true piston against the node's LuGre position (the float reference);
- path: the summed |increments|, the true piston's against the node's
  dissipation path (its LuGre position through the play);
- the seal friction's change over the window and its level at T1 (mean of
  0.1 s either side), the plant's against the node's.

`--set KEY=VALUE` (JSON value) changes one setting of the commissioned
`physical` section first, as tools/observer_sensitivity.py does; e.g.
`--set stroke_sigmas=0` runs the node without the stroke tracking.

    .venv/bin/python tools/seal_creep.py out/evaluate/runs/payload-12t 124.6 128.2
    .venv/bin/python tools/seal_creep.py out/evaluate/runs/duty-cycle-50 196 220 --set stroke_sigmas=0
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ropemon.commission import reference


def _change(a: np.ndarray, i0: int, i1: int, w: int) -> np.ndarray:
    """Mean over +-w samples around i1 minus that around i0, per column."""
    return a[i1 - w:i1 + w].mean(0) - a[i0 - w:i0 + w].mean(0)


def creep(run: Path, t0: float, t1: float, settings: dict | None = None) -> list[tuple[str, np.ndarray]]:
    """(label, value per rope) rows for the window [t0, t1] s of `run`, with `settings`
    replacing keys of the commissioned physical section; ValueError if the window
    (with its 0.1 s either side) is not inside the run."""
    ph = json.loads((run / "node-evaluated.json").read_text())["physical"]
    ph.update(settings or {})
    _r, hz, recs = reference.read_rsens(run / "sim" / "sensors.rsens")
    truth = np.load(run / "sim" / "truth.npz")
    x_true = np.asarray(truth["piston_x_m"], float)
    w = max(1, hz // 10)
    i0, i1 = int(round(t0 * hz)), int(round(t1 * hz))
    end = min(len(recs), len(x_true)) - w
    if not (w <= i0 < i1 <= end):
        raise ValueError(f"window {t0:g}-{t1:g} s must lie inside the run ({w / hz:.1f}-{end / hz:.1f} s)")
    inc: dict = {}
    comp = reference.compensate(ph, recs[: i1 + w], increments=inc)  # causal: the rest is not needed
    x_node = np.cumsum(inc["dxs"], axis=0)
    return [
        ("creep, true piston (um)", 1e6 * _change(x_true, i0, i1, w)),
        ("creep, node's LuGre position (um)", 1e6 * _change(x_node, i0, i1, w)),
        # the increments into samples i0 .. i1-1, as the node's dxp[i0:i1]
        ("path, true piston (um)", 1e6 * np.abs(np.diff(x_true[i0 - 1:i1], axis=0)).sum(0)),
        ("path, node's dissipation (um)", 1e6 * np.abs(inc["dxp"][i0:i1]).sum(0)),
        ("seal friction change, plant (kN)", _change(np.asarray(truth["friction_N"], float), i0, i1, w) / 1e3),
        ("seal friction change, node (kN)", _change(comp.friction_n, i0, i1, w) / 1e3),
        (f"seal friction at {t1:g} s, plant (kN)", np.asarray(truth["friction_N"][i1 - w:i1 + w], float).mean(0) / 1e3),
        (f"seal friction at {t1:g} s, node (kN)", comp.friction_n[i1 - w:i1 + w].mean(0) / 1e3),
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="out/evaluate/runs/NAME")
    ap.add_argument("t0", type=float, help="window start (s)")
    ap.add_argument("t1", type=float, help="window end (s)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="change a setting of the physical section (JSON value); repeatable")
    a = ap.parse_args(argv)
    settings = {}
    for item in a.set:
        key, sep, value = item.partition("=")
        try:
            if not sep:
                raise ValueError("expected KEY=VALUE")
            settings[key] = json.loads(value)
        except ValueError as e:
            ap.error(f"--set {item}: {e}")
    try:
        rows = creep(a.run, a.t0, a.t1, settings)
    except ValueError as e:
        ap.error(str(e))
    ropes = len(rows[0][1])
    changed = "".join(f", {k}={json.dumps(v)}" for k, v in settings.items())
    print(f"{a.run}: {a.t0:g}-{a.t1:g} s{changed}")
    print("| | " + " | ".join(f"rope {i + 1}" for i in range(ropes)) + " |")
    print("|---|" + "---:|" * ropes)
    for label, v in rows:
        print(f"| {label} | " + " | ".join(f"{x:+.2f}" for x in v) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
