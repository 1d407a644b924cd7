"""`ropemon study seed-spread [SCENARIO ...] [--seeds 1-10] [--jobs 2] [--out DIR] [--quick]`:
how much the full compensation's figures move with the noise seed.

`ropemon evaluate` runs one seed: one draw of the sensor noise, of the test bed's
noise (so one friction fit) and of the commissioning wind (so one k and one
pressure noise). This runs `ropemon evaluate SCENARIO... --seed N --no-firmware
--json --out OUT/seed-N` for several seeds, exactly as a user would, and prints, per
scenario, the spread of `lugre-p+loss` against the pithead target
(`evaluate.TARGETS`). The firmware is left out (`ropemon evaluate` without
--no-firmware compares it with the float reference). OUT/seed-N/runs/SCENARIO are the
run directories `ropemon study pithead-spread` recombines.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from ropemon.lab.studies import pithead_target_pct, seed_range

# the single-wind scenarios with a LuGre seal and the default sensors: where the
# pithead target applies
DEFAULT_SCENARIOS = ("paper-field-trip", "payload-0t", "payload-12t", "oil-0C", "oil-20C", "oil-40C",
                     "oil-0C-temp-input", "oil-40C-temp-input", "rope-length-5cm", "pithead-long-rest")
ESTIMATOR = "lugre-p+loss"


def run_seed(seed: int, scenarios: list[str], out: Path, quick: bool = False) -> dict:
    """One `ropemon evaluate` run; its JSON."""
    cmd = [sys.executable, "-m", "ropemon.cli", "evaluate", *scenarios, "--seed", str(seed),
           "--no-firmware", "--json", "--out", str(out / f"seed-{seed}"), *(["--quick"] if quick else [])]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if not res.stdout.strip():
        raise SystemExit(f"seed {seed}: `{' '.join(cmd[2:])}` printed no JSON (exit {res.returncode}):\n"
                         f"{res.stderr[-2000:]}")
    return json.loads(res.stdout)


def _span(values: list[float]) -> str:
    return f"{min(values):+.2f} / {statistics.median(values):+.2f} / {max(values):+.2f}"


def table(results: dict[int, dict], scenarios: list[str]) -> str:
    target = pithead_target_pct()
    seeds = sorted(results)
    lines = [f"| scenario | rope RMS % (worst seed) | rope peak % (worst seed) | pithead empty % min / median / max "
             f"| seeds within {target} % | pithead as arrived % min / median / max "
             f"| false @8 % / missed @12 % (frames, all seeds) | operator alarms: false @8 % / missed @12 % "
             f"(frames, all seeds) | commissioned |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name in scenarios:
        rows = [results[s]["scenarios"][name] for s in seeds if name in results[s]["scenarios"]]
        est = [r["estimators"][ESTIMATOR] for r in rows]
        rms = max(e["rope_rms_pct"] for e in est)
        peak = max(e["rope_peak_pct"] for e in est)
        empty = [e["pithead_empty_total_pct"] for e in est if e.get("pithead_empty_total_pct") is not None]
        arrived = [e["pithead_arrival_total_pct"] for e in est if e.get("pithead_arrival_total_pct") is not None]
        within = sum(abs(v) <= target for v in empty)
        false8 = sum(e["alarms"]["8"]["false"] for e in est)
        missed12 = sum(e["alarms"]["12"]["missed"] for e in est)
        false_alarms = sum(e["alarms"]["8"]["false_alarms"] for e in est)
        missed_alarm = sum(e["alarms"]["12"]["missed_alarm_frames"] for e in est)
        ok = sum(bool(r["commissioning"].get("ok")) for r in rows)
        lines.append(f"| {name} | {rms:.2f} | {peak:.2f} | {_span(empty) if empty else '-'} "
                     f"| {within} of {len(empty)} | {_span(arrived) if arrived else '-'} "
                     f"| {false8} / {missed12} | {false_alarms} / {missed_alarm} | {ok} of {len(rows)} |")
    lines.append("")
    lines.append("Pithead empty % per seed (" + ", ".join(str(s) for s in seeds) + "):")
    lines.append("")
    for name in scenarios:
        vals = [results[s]["scenarios"][name]["estimators"][ESTIMATOR].get("pithead_empty_total_pct")
                for s in seeds]
        lines.append(f"- {name}: " + ", ".join("-" if v is None else f"{v:+.2f}" for v in vals))
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenarios", nargs="*", default=list(DEFAULT_SCENARIOS), metavar="SCENARIO",
                   help="default: the single winds with a LuGre seal and the default sensors")
    p.add_argument("--seeds", default="1-10", help="e.g. 1-10 or 1,4,7 (default 1-10)")
    p.add_argument("--jobs", type=int, default=2, help="seeds evaluated at once (default 2)")
    p.add_argument("--out", type=Path, default=Path("out/seed-spread"), help="work directory (default out/seed-spread)")
    p.add_argument("--quick", action="store_true", help="the short test bed of `ropemon evaluate --quick`")


def run(args: argparse.Namespace) -> int:
    seeds = seed_range(args.seeds)
    t0 = time.monotonic()
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        runs = dict(zip(seeds, pool.map(lambda s: run_seed(s, args.scenarios, args.out, args.quick), seeds)))
    errors = [f"seed {s}: {name}: {r['error']}" for s, res in sorted(runs.items())
              for name, r in res["scenarios"].items() if "error" in r]
    if errors:  # a scenario that could not be evaluated (a bad scenario file, ...): said, not tabulated
        print("ropemon study seed-spread: " + "\n  ".join(["evaluation failed:", *errors]), file=sys.stderr)
        return 1
    print(f"## `{ESTIMATOR}` over {len(seeds)} seeds ({args.seeds})\n")
    print(table(runs, args.scenarios))
    quick = " --quick" if args.quick else ""
    print(f"\n(made by `ropemon study seed-spread {' '.join(args.scenarios)} --seeds {args.seeds}{quick}` "
          f"in {time.monotonic() - t0:.0f} s)")
    return 0
