"""`ropemon study NAME ...`: the lab's accuracy studies, whose figures docs/accuracy.md,
docs/model.md, docs/commissioning.md and docs/fitting.md quote.

Each study reads run directories (`ropemon.lab.rundir`) as `ropemon evaluate --out DIR`
leaves them (DIR/runs/SCENARIO), or runs the evaluation itself, and prints its figures as
Markdown. One module per study, each with `add_arguments(parser)` and `run(args) -> int`.
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys

# study -> (module, one-line help)
STUDIES = {
    "observer-sensitivity": ("observer_sensitivity",
                             "the full compensation with one observer setting changed at a time"),
    "observer-losses": ("observer_losses", "the friction error stage by stage: true position, tracker, play, node"),
    "seed-spread": ("seed_spread", "the full compensation's figures over noise seeds (`ropemon evaluate` per seed)"),
    "pithead-spread": ("pithead_spread", "where the pithead total's seed-to-seed spread comes from"),
    "pithead-bound": ("pithead_bound", "the least spread of the pithead total the transmitters' noise allows"),
    "balancing-strokes": ("balancing_strokes", "how the pistons share the oil's motion in a wind's truth"),
    "stroke-events": ("stroke_events", "the balancing strokes the node and the float reference take"),
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="study", metavar="STUDY")
    sub.required = True
    for name, (module, help_) in STUDIES.items():
        sp = sub.add_parser(name, help=help_, description=help_)
        mod = importlib.import_module(f"{__name__}.{module}")
        mod.add_arguments(sp)
        sp.set_defaults(_study=mod)


def run(args: argparse.Namespace) -> int:
    from ropemon.lab.evaluate import EvaluationError
    from ropemon.lab.rundir import RunDirError

    try:
        return int(args._study.run(args) or 0)
    except (RunDirError, EvaluationError, OSError) as e:  # a run directory that is not one, a scenario that is not
        what = f"{e.filename}: cannot read: {e.strerror}" if isinstance(e, OSError) and e.filename else str(e)
        print(f"ropemon study {args.study}: {what}", file=sys.stderr)
        return 2


# ---------------------------------------------------------------- shared by the studies


def pithead_target_pct() -> float:
    """The pithead total's target, % of the true total (`evaluate.TARGETS`)."""
    from ropemon.lab.evaluate import TARGETS

    return TARGETS["pithead_total_pct"]


def seed_range(text: str) -> list[int]:
    """'1-10' or '1,3,5' -> seeds."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


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


def fmt(x, digits: int = 2, sign: bool = False) -> str:
    """A figure, or `-` where there is none (None or not finite)."""
    import math

    if x is None or not math.isfinite(x):
        return "-"
    return f"{x:{'+' if sign else ''}.{digits}f}"
