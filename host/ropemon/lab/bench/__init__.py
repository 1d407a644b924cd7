"""`ropemon bench PART [--json]`: benchmarks print their figures; tests check behaviour.

Each part is a module here with `measure(quick: bool) -> dict` returning the
figures (medians of repeats, with the baseline measured in the same run) and
`describe(figures) -> str` for the human-readable form.
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys

PARTS = ("firmware", "plant", "host", "noise", "opcua", "mqtt", "modbus", "web", "fleet")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("part", choices=PARTS, help="what to measure")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    p.add_argument("--quick", action="store_true", help="fewer repeats (a smoke run, not for the docs)")


def run(args: argparse.Namespace) -> int:
    mod = importlib.import_module(f"ropemon.lab.bench.{args.part}")
    figures = mod.measure(quick=args.quick)
    if args.json:
        json.dump(figures, sys.stdout)
        sys.stdout.write("\n")
    else:
        print(mod.describe(figures))
    return 0
