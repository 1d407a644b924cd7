"""`ropemon study observer-sensitivity [SCENARIO] [--out DIR] [--seed N] [--quick]`: how the
full compensation's accuracy depends on the friction observer's settings.

Commissions and simulates a scenario as `ropemon evaluate` does (no firmware run; the run
directory is OUT/SCENARIO), then reruns the float reference `lugre-p+loss` with one setting
changed at a time: the play multiplier `friction_play_sigmas`, the hydraulic compliance k
scaled (as if fit-compliance were that far off), the pressure tracker's bounce frequency
(as if fit-compliance had measured it that far off), damping and process noises, the
threshold of the balancing-stroke tracking (`stroke_sigmas`; 0: none), the rest hold's
threshold (`rest_sigmas`; 0: none), and no compliance at all. Prints a Markdown table
(the figures of docs/model.md, docs/commissioning.md and docs/fitting.md on a wrong k or
bounce, and on no compliance).
"""
from __future__ import annotations

import argparse
import copy
import time
from pathlib import Path

from ropemon.commission import reference
from ropemon.commission.nodejson import DEFAULTS, physical_params
from ropemon.lab import evaluate as EV
from ropemon.lab import metrics as M
from ropemon.lab.rundir import RunDir
from ropemon.lab.studies import fmt


def variants(ph: dict) -> list[tuple[str, dict]]:
    """(label, physical) pairs: the commissioned config and one change each."""
    out = [("as commissioned", ph)]
    for m in (1.2, 1.3, 1.6, 1.7, 2.0):
        out.append((f"friction_play_sigmas {m:g}", dict(ph, friction_play_sigmas=m)))
    k = ph.get("hydraulic_compliance_m_per_Pa")
    if k:
        for f in (0.95, 0.98, 1.02, 1.05):
            out.append((f"k x {f:g}", dict(ph, hydraulic_compliance_m_per_Pa=[x * f for x in k])))
        fb = float(ph.get("bounce_hz", DEFAULTS["bounce_hz"]))
        for d in (-0.3, 0.3):
            out.append((f"bounce_hz {fb + d:.2f} ({d:+g} Hz)", dict(ph, bounce_hz=fb + d)))
        for z in (0.1, 0.3):
            out.append((f"bounce_filter_damping {z:g}", dict(ph, bounce_filter_damping=z)))
        for key in ("creep_q_Pa2_s3", "bounce_q_Pa2_s3"):
            for f in (1 / 3, 3):
                out.append((f"{key} x {f:.3g}", dict(ph, **{key: float(ph.get(key, DEFAULTS[key])) * f})))
        for m in (4.5, 8.5):
            out.append((f"stroke_sigmas {m:g}", dict(ph, stroke_sigmas=m)))
        out.append(("balancing strokes not tracked (stroke_sigmas 0)", dict(ph, stroke_sigmas=0.0)))
        for m in (0.75, 1.5):
            out.append((f"rest_sigmas {m:g}", dict(ph, rest_sigmas=m)))
        out.append(("no rest hold (rest_sigmas 0)", dict(ph, rest_sigmas=0.0)))
        no_k = copy.deepcopy(ph)
        for key in ("hydraulic_compliance_m_per_Pa", "pressure_noise_Pa", "bounce_hz"):
            no_k.pop(key, None)
        out.append(("no compliance (1 Hz position low-pass)", no_k))
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", nargs="?", default=EV.FIELD_TRIP, help=f"a scenario name (default {EV.FIELD_TRIP})")
    p.add_argument("--out", type=Path, default=Path("out/sensitivity"), help="work directory (default out/sensitivity)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--quick", action="store_true", help="the short test bed of `ropemon evaluate --quick`")


def run(args: argparse.Namespace) -> int:
    t0 = time.monotonic()
    case = EV.build_case(args.scenario, args.out / args.scenario, args.seed, firmware=False,
                         bed=EV.BED_QUICK if args.quick else None, diagnostics=False)
    recs = RunDir(args.out / args.scenario).records[: len(case.truth_n)]
    print(f"## {args.scenario}: `lugre-p+loss` with one observer setting changed\n")
    print("| setting | play (um) | rope RMS % | rope peak % | pithead empty % | pithead as arrived % |")
    print("|---|---:|---:|---:|---:|---:|")
    for label, ph in variants(case.physical):
        est = reference.compensate(ph, recs).tension_n
        f = M.evaluate_estimate(est, case.truth_n, case.rated_n, case.phase, case.excluded, case.steady,
                                case.payload_kg)
        play_um = physical_params(ph)["play_m"] * 1e6
        print(f"| {label} | {play_um:.2f} | {f['rope_rms_pct']:.2f} | {f['rope_peak_pct']:.2f} | "
              f"{fmt(f.get('pithead_empty_total_pct'))} | {fmt(f.get('pithead_arrival_total_pct'))} |")
    quick = " --quick" if args.quick else ""
    print(f"\n(made by `ropemon study observer-sensitivity {args.scenario} --seed {args.seed}{quick}` "
          f"in {time.monotonic() - t0:.0f} s)")
    return 0
