"""Leave-one-family-out: how the node does on each seal family, phase by phase, against raw p x A.

`ropemon evaluate --leave-one-family-out N` (docs/evaluation/generalisation.md). The seal
families are the population's (`population.LAWS`: LuGre, Maxwell-slip, elasto-plastic) and
the two it never draws (`population.HELD_OUT_LAWS`: Dahl, Bliman-Sorine). For each family F in
turn, N hoists of F are drawn on the scoring seeds and scored; the settings they run with should
have been chosen on the tuning hoists of the other families only (`tuning_hoists_for`).

Which seeds are which family (`family_seeds`), seeded and reproducible:
- a present family's hoists are the population's own: the scoring seeds whose `population.draw`
  gives that law, in seed order (the same hoists as docs/evaluation/population.md);
- each scoring seed also has one held-out family, from a stream of its own
  (`held_out_family`: numpy's generator on [seed, HELD_OUT_STREAM]), so `population.draw` is
  untouched. A held-out family's hoist is that seed's drawn hoist with its seal replaced by
  `population.seal_table(F, draws, force_scale)`: the same bore, hoses, offsets, parting ropes,
  oil, payload and noise seed, only the seal's law differs.

What the node's commissioning chooses per hoist (the seal fitted on that hoist's test bed, its
compliance on its own commissioning wind) is not chosen on the population. What is chosen on
the population are constants of the node and the station (`SETTINGS_CHOSEN`), chosen by hand on
the tuning seeds 1-20, whose draws hold only the present families: for a held-out family they
were chosen on other families' seeds only; for a present family its own tuning seeds were among
them, and the report says how many.

Scored per hoist (`wind_figures`) on the node's 10 Hz frame means (the firmware under
MicroPython) and on raw p x A (the tap pressure times the bore's area, no friction and no pipe
loss: `estimators` "raw"), both against the truth averaged over the same windows, per phase
(`metrics.classify_phases`; the rests include the loading at the bottom and the unloading at the
top) and over the whole wind: the worst rope's RMS in % of rated, each rope's, and the RMS of the
summed tension in % of the rated total (ropes x rated). *Do no harm* (`do_no_harm`): at each
rest, the compensated total and every rope no further from the truth (RMS over the rest) than
raw p x A's plus DNH_MARGIN_PCT % of rated.
"""
from __future__ import annotations

import dataclasses
import json
import shutil
import time
from pathlib import Path

import numpy as np

from ropemon.lab import metrics as M
from ropemon.lab import population as P

FAMILIES = P.LAWS + P.HELD_OUT_LAWS
HELD_OUT_STREAM = 0x6E0F
DNH_MARGIN_PCT = 0.5
WIND = "wind"
# (metrics.PHASES name, column heading), in the order of a wind
PHASE_COLUMNS = (("rest-bottom", "rest at the bottom, with loading"), ("acceleration", "acceleration"),
                 ("constant-speed", "constant speed"), ("deceleration", "deceleration"),
                 ("reversal-creep", "creep (moving under 0.5 m/s)"),
                 ("rest-pithead", "rest at the top, with unloading"), (WIND, "whole wind"))
RESTS = ("rest-bottom", "rest-pithead")
ESTIMATORS = ("node", "raw")
# What is chosen on the population's tuning seeds (by hand, shipped as constants): docs/config.md,
# docs/accuracy.md.
SETTINGS_CHOSEN = ("the node's slide following (`slide_follow_lo_sigmas` 3, `slide_follow_hi_sigmas` 5)",
                   "the station's equalizer rules (and `position_lag` and the band's anchor left off)")
# chosen on the named scenarios of the field trip (docs/accuracy.md), whose seal is LuGre
SETTINGS_ON_FIELD_TRIP = "several of the node's observer settings (docs/accuracy.md)"


# ---------------------------------------------------------------- the split


def held_out_family(seed: int) -> str:
    """The held-out family a seed's hoist takes in this evaluation (its own stream: `population.draw`
    of the seed is not changed)."""
    rng = np.random.default_rng([seed, HELD_OUT_STREAM])
    return P.HELD_OUT_LAWS[int(rng.integers(len(P.HELD_OUT_LAWS)))]


def is_family(seed: int, family: str) -> bool:
    if family in P.LAWS:
        return P.draw(seed).law == family
    if family in P.HELD_OUT_LAWS:
        return held_out_family(seed) == family
    raise ValueError(f"unknown seal family {family!r}; known: {', '.join(FAMILIES)}")


def family_seeds(family: str, n: int | None = None, pool=P.SCORING_SEEDS) -> list[int]:
    """The first n seeds of `pool` (all: None) that are of `family`, in seed order."""
    out = [s for s in pool if is_family(s, family)]
    return out if n is None else out[:n]


def families_of(seed: int) -> tuple[str, str]:
    """The two families a seed's hoist is evaluated in: its drawn law and its held-out family."""
    return P.draw(seed).law, held_out_family(seed)


def tuning_hoists_for(family: str) -> list[tuple[str, int]]:
    """The tuning hoists (family, seed) of the other families: where a setting for `family` may be
    chosen when it is left out."""
    return [(g, s) for s in P.TUNING_SEEDS for g in families_of(s) if g != family]


def settings_seeds_of(family: str) -> list[int]:
    """The tuning seeds of `family` among those the shipped settings were chosen on (the population's
    present draws of TUNING_SEEDS): none for a held-out family."""
    return [s for s in P.TUNING_SEEDS if P.draw(s).law == family]


def hoist(family: str, seed: int) -> P.Hoist:
    """The hoist of `seed` in `family`: the drawn hoist, its seal in a held-out law if asked."""
    h = P.draw(seed)
    if family == h.law:
        return h
    if family not in P.HELD_OUT_LAWS:
        raise ValueError(f"seed {seed} draws a {h.law} seal, not {family}")
    return dataclasses.replace(h, law=family, friction=P.seal_table(family, h.draws, h.friction["force_scale"]))


def scenario_name(family: str, seed: int) -> str:
    return f"{P.PREFIX}{seed}" if family in P.LAWS else f"{P.PREFIX}{family}-{seed}"


def _toml_doc(doc: dict) -> str:
    """A scenario document as TOML (top-level scalars, then one table per section, its values
    inline), checked to read back the same."""
    import tomllib

    from ropemon.lab.evaluate import EvaluationError, _toml

    head = [f"{k} = {_toml(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    body = []
    for k, v in doc.items():
        if isinstance(v, dict):
            body += [f"[{k}]", *(f"{kk} = {_toml(vv)}" for kk, vv in v.items())]
    text = "\n".join(head + body) + "\n"
    if tomllib.loads(text) != doc:
        raise EvaluationError("the held-out hoist's scenario does not survive writing as TOML")
    return text


def scenario_for(family: str, seed: int, work: Path) -> str:
    """What `evaluate.build_case` takes for the hoist: a present family's population name, or the
    path of a scenario file written into `work` (the drawn hoist's scenario with its seal replaced)."""
    from ropemon.lab import evaluate as EV

    name = scenario_name(family, seed)
    if family in P.LAWS:
        return name
    h = hoist(family, seed)
    doc, _path = EV.scenario_doc(f"{P.PREFIX}{seed}", work)   # the drawn hoist; its site copy in `work`
    doc["name"] = name
    doc["plant"]["friction"] = dict(h.friction)
    work.mkdir(parents=True, exist_ok=True)
    path = work / f"{name}.toml"
    path.write_text(_toml_doc(doc))
    return str(path)


# ---------------------------------------------------------------- scoring


def frame_arrays(case) -> dict:
    """Per frame: the truth, the node's means, raw p x A, the phase and the frames that count."""
    from ropemon.lab import estimators as E

    w = case.window
    n = min(len(case.firmware_n), len(case.truth_n) // w)
    return {"truth": M.window_means(case.truth_n, w)[:n], "node": np.asarray(case.firmware_n[:n], float),
            "raw": M.window_means(case.estimates[E.STATIC_FRICTION_LAWS[0]], w)[:n],
            "phase": np.asarray(case.phase[: n * w: w]),
            "keep": M.window_means(case.excluded.astype(float), w)[:n] == 0.0}


def phase_figures(est: np.ndarray, truth: np.ndarray, phase: np.ndarray, keep: np.ndarray,
                  rated_n: float) -> dict:
    """Per phase (PHASE_COLUMNS) and over the wind: worst-rope and per-rope RMS (% of rated) and the
    total's RMS (% of the rated total); None for a phase the wind does not have."""
    out = {}
    for name, _label in PHASE_COLUMNS:
        where = keep if name == WIND else keep & (phase == M.PHASES.index(name))
        if not where.any():
            out[name] = None
            continue
        f = M.error_figures(est, truth, rated_n, where)
        out[name] = {"rope_rms_pct": f["rope_rms_pct"], "per_rope_rms_pct": f["per_rope_rms_pct"],
                     "total_rms_pct": f["total_rms_pct"], "frames": f["samples"]}
    return out


def wind_figures(arrays: dict, rated_n: float) -> dict:
    """`phase_figures` of the node and of raw p x A, and the do-no-harm check at each rest."""
    figs = {e: phase_figures(arrays[e], arrays["truth"], arrays["phase"], arrays["keep"], rated_n)
            for e in ESTIMATORS}
    return {"phases": figs, "do_no_harm": {r: do_no_harm(figs["node"][r], figs["raw"][r]) for r in RESTS}}


def do_no_harm(node: dict | None, raw: dict | None, margin_pct: float = DNH_MARGIN_PCT) -> dict | None:
    """Whether the node's total and every rope are within raw p x A's error plus `margin_pct` (RMS
    over one rest, % of rated; the total's of the rated total), and the largest excess (node - raw)
    over the ropes and the total. None when the rest is missing."""
    if node is None or raw is None:
        return None
    pairs = [("total", node["total_rms_pct"], raw["total_rms_pct"])]
    pairs += [(f"rope {i + 1}", a, b) for i, (a, b) in enumerate(zip(node["per_rope_rms_pct"],
                                                                       raw["per_rope_rms_pct"]))]
    pairs = [(k, a, b) for k, a, b in pairs if np.isfinite(a) and np.isfinite(b)]
    if not pairs:
        return None
    worst = max(pairs, key=lambda p: p[1] - p[2])
    excess = float(worst[1] - worst[2])
    return {"ok": bool(all(a <= b + margin_pct for _k, a, b in pairs)), "excess_pct": round(excess, 4),
            "worst": worst[0], "ropes_ok": bool(all(a <= b + margin_pct for k, a, b in pairs if k != "total")),
            "total_ok": bool(all(a <= b + margin_pct for k, a, b in pairs if k == "total"))}


# ---------------------------------------------------------------- running


def case_from_run(run_dir) -> "EV.Case":
    """What `frame_arrays` needs of a wind already run and commissioned (a population run's
    directory, `population.run_wind`): its truth and phases, the node's frames and raw p x A (the
    float reference's tap pressure times the area, as `evaluate.build_case` makes it)."""
    from ropemon.commission import reference
    from ropemon.lab import evaluate as EV
    from ropemon.lab.rundir import RunDir

    run = RunDir(run_dir)
    ph = run.physical
    sc = run.scoring(ph)
    full = reference.compensate(ph, run.records[: run.length])
    raw = np.where(full.good, full.p_pa * np.asarray(ph["cylinder_area_m2"], float), np.nan)
    return EV.Case(name=Path(run_dir).name, sample_hz=run.sample_hz, frame_hz=int(ph["frame_hz"]),
                   rated_n=sc.rated_n, truth_n=sc.truth_n, phase=sc.phase, excluded=sc.excluded,
                   estimates={"raw": raw}, firmware_n=EV.frame_means_n(run.frames()), physical=ph)


def reusable(run_dir) -> bool:
    """Whether a population run left a commissioned, replayed wind there."""
    from ropemon.lab.rundir import FRAMES, NODE_EVALUATED

    d = Path(run_dir)
    return (d / FRAMES).is_file() and (d / NODE_EVALUATED).is_file() and (d / "sim" / "truth.npz").is_file()


def run_hoist(family: str, seed: int, work, bed: dict | None = None, reuse=None) -> dict:
    """Draw (in `family`), commission, run the node on and score one hoist; errors are reported.
    `reuse`: a population run's directory (OUT/population): a present family's hoist run there is
    scored from its wind instead of being simulated again (the same hoist, seed and node)."""
    from ropemon.lab import evaluate as EV

    t0 = time.monotonic()
    h = hoist(family, seed)
    out: dict = {"family": family, "seed": seed, "hoist": h.describe()}
    if reuse is not None and family in P.LAWS and reusable(Path(reuse) / h.name):
        out["reused"] = str(Path(reuse) / h.name)
        out["commissioning"] = {"ok": True, "problems": [], "seal_refused": None}
        try:
            out["friction_check"] = friction_check(EV.fit_plant_seal(dict(h.friction), Path(reuse), seed, bed),
                                                   Path(reuse))
            case = case_from_run(Path(reuse) / h.name)
            out.update(wind_figures(frame_arrays(case), case.rated_n))
        except (EV.EvaluationError, OSError, ValueError, KeyError) as e:
            out["error"] = f"{type(e).__name__}: {e}"
        out["wall_s"] = round(time.monotonic() - t0, 1)
        return out
    # each hoist its own directory, and in it the case's (`build_case` caches the seal's fit one up)
    hdir = Path(work) / scenario_name(family, seed)
    wdir = hdir / "case"
    shutil.rmtree(hdir, ignore_errors=True)   # a lifted fit of an earlier run must not be read as the fit
    try:
        name = scenario_for(family, seed, hdir)
        fit = EV.fit_plant_seal(dict(h.friction), hdir, seed, bed)
        out["friction_check"] = friction_check(fit, hdir)
        out["lifted"] = lift_fit(fit, hdir)
        case = EV.build_case(name, wdir, seed, True, bed, diagnostics=False)
    except (EV.EvaluationError, OSError, ValueError, KeyError) as e:
        # the commissioning refusing the seal is an outcome (the node is not installed), not an error
        why = f"{type(e).__name__}: {e}"
        out["not_commissioned" if is_commissioning_refusal(e) else "error"] = why
        out["wall_s"] = round(time.monotonic() - t0, 1)
        return out
    c = case.commissioning
    out["commissioning"] = {"ok": bool(c["ok"]), "problems": c["problems"], "seal_refused": c["seal_refused"]}
    if case.firmware_n is None:
        out["refused"] = "; ".join(c["problems"]) or "the node did not run"
    else:
        out.update(wind_figures(frame_arrays(case), case.rated_n))
    out["wall_s"] = round(time.monotonic() - t0, 1)
    return out


def friction_check(fit: dict, cache_dir) -> str | None:
    """The verdict of `ropemon fit-friction`'s own check on the bed (`calibrate.check_bed` on the bed's
    record beside the fit's cache in `cache_dir`): "ok", "marginal", "worse" (fit-friction writes no
    fit), "error: ..." (the check cannot run the fit: fit-friction writes none either); None: no
    record found. The evaluation's own fit (`evaluate.fit_plant_seal`) does not run the check."""
    from ropemon.commission import calibrate

    if isinstance(fit.get("check"), dict):
        return fit["check"].get("verdict")
    csvs = [c.with_suffix(".csv") for c in Path(cache_dir).glob("friction-*.json")
            if json.loads(c.read_text()) == fit]
    csvs = [c for c in csvs if c.is_file()]
    if not csvs:
        return None
    try:
        return calibrate.check_bed(calibrate.read_csv(csvs[0]), fit).verdict
    except (calibrate.FitError, ValueError) as e:
        return f"error: {e}"


def accepted(r: dict) -> bool:
    """Whether the commissioning as shipped would have installed the node on a scored hoist: the fit
    passes the site's check unlifted, its own check is not "worse", and `ropemon config` takes the seal."""
    return ("phases" in r and not r.get("lifted") and not refused_by_check(r)
            and not r["commissioning"]["seal_refused"])


def refused_by_check(r: dict) -> bool:
    v = r.get("friction_check")
    return v == "worse" or (v or "").startswith("error")


def is_commissioning_refusal(e: Exception) -> bool:
    """`ropemon fit-friction` refusing the seal's test-bed record, or `ropemon config` refusing the
    fit (`SiteError`)."""
    from ropemon.commission.site import SiteError

    return isinstance(e, SiteError) or str(e).startswith("fit-friction")


def lift_fit(fit: dict, cache_dir: Path) -> str | None:
    """A fit whose Fs line falls below its Fc line (a seal without a static peak: Dahl's) is refused
    by the site's check (`physical.friction_from_dict`). To score the node on such a seal anyway, its
    Fs line is lifted to the larger slope and intercept of the two (at least Fc at every pressure)
    in the fit's cache in `cache_dir` (the file holding this fit), which `build_case` then reads. Returns
    the check's refusal (None: the fit passes and is left alone)."""
    from ropemon.station.physical import PhysicalError, friction_from_dict

    p_max = float(max(fit.get("pressure_range_MPa", [12.0])))
    try:
        friction_from_dict(fit, p_max)
        return None
    except PhysicalError as e:
        why = str(e)
    fs, fc = fit["Fs"], fit["Fc"]
    if "Fs" not in why.split(":")[0]:
        return None   # another refusal: left to the commissioning to report
    caches = [c for c in Path(cache_dir).glob("friction-*.json") if json.loads(c.read_text()) == fit]
    if not caches:
        raise ValueError(f"{cache_dir}: the friction fit to lift is not there")
    lifted = dict(fit, Fs=dict(fs, slope=max(fs["slope"], fc["slope"]), intercept=max(fs["intercept"],
                                                                                         fc["intercept"])))
    for c in caches:
        c.write_text(json.dumps(lifted, indent=1))
    return why


def _run_one(args):
    return run_hoist(*args)


def run(families, n: int, work, jobs: int = 2, bed: dict | None = None, log=None, pool=P.SCORING_SEEDS,
        reuse=None) -> list:
    """`run_hoist` over the first n seeds of `pool` of each family, `jobs` at a time."""
    from concurrent.futures import ProcessPoolExecutor

    tasks = [(f, s, work, bed, reuse) for f in families for s in family_seeds(f, n, pool)]
    results = []
    if jobs <= 1:
        for t in tasks:
            results.append(run_hoist(*t))
            if log:
                log(_line(results[-1]))
        return results
    with ProcessPoolExecutor(max_workers=jobs) as ex:
        for r in ex.map(_run_one, tasks):
            results.append(r)
            if log:
                log(_line(r))
    return results


def _line(r: dict) -> str:
    head = f"{scenario_name(r['family'], r['seed'])}: "
    if "error" in r:
        return head + f"ERROR {r['error']} ({r['wall_s']} s)"
    if "refused" in r or "not_commissioned" in r:
        return head + f"not commissioned: {r.get('refused') or r['not_commissioned']} ({r['wall_s']} s)"
    ph = r["phases"]
    return head + (f"wind RMS node {ph['node'][WIND]['rope_rms_pct']:.2f} % raw {ph['raw'][WIND]['rope_rms_pct']:.2f} %"
                   f"; do no harm " + ", ".join(f"{k} {'ok' if v and v['ok'] else 'NO'}"
                                                 for k, v in r["do_no_harm"].items()) + f" ({r['wall_s']} s)")


# ---------------------------------------------------------------- summary and report


def _mm(values) -> dict:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], float)
    if not v.size:
        return {"median": None, "max": None, "n": 0}
    return {"median": round(float(np.median(v)), 3), "max": round(float(v.max()), 3), "n": int(v.size)}


def family_summary(results: list[dict]) -> dict:
    """Over one family's hoists (or any list): per phase, the node's and raw's worst-rope RMS and the
    total's (median, max); per rest the do-no-harm share and its worst excess."""
    scored = [r for r in results if "phases" in r]
    out: dict = {"seeds": [r["seed"] for r in results], "scored": len(scored),
                 "refused": [r["seed"] for r in results if "refused" in r],
                 "errors": [r["seed"] for r in results if "error" in r],
                 "not_commissioned": [r["seed"] for r in results if "not_commissioned" in r],
                 "seal_refused": [r["seed"] for r in scored if r["commissioning"]["seal_refused"]],
                 "lifted": [r["seed"] for r in results if r.get("lifted")],
                 "phases": {}}
    for name, _label in PHASE_COLUMNS:
        out["phases"][name] = {e: {k: _mm((r["phases"][e][name] or {}).get(k) for r in scored)
                                   for k in ("rope_rms_pct", "total_rms_pct")} for e in ESTIMATORS}
    out["check_worse"] = [r["seed"] for r in results if refused_by_check(r)]
    out["accepted"] = [r["seed"] for r in scored if accepted(r)]
    for key, rs in (("do_no_harm", scored), ("do_no_harm_accepted", [r for r in scored if accepted(r)])):
        out[key] = {}
        for rest in RESTS:
            d = [(r["seed"], r["do_no_harm"][rest]) for r in rs if r["do_no_harm"][rest] is not None]
            worst = max(d, key=lambda x: x[1]["excess_pct"]) if d else None
            out[key][rest] = {
                "winds": len(d), "ok": sum(x["ok"] for _s, x in d),
                "share": round(sum(x["ok"] for _s, x in d) / len(d), 3) if d else None,
                "worst_excess_pct": worst[1]["excess_pct"] if worst else None,
                "worst": f"seed {worst[0]}, {worst[1]['worst']}" if worst else None}
    return out


def summary(results: list[dict], families) -> dict:
    by = {f: family_summary([r for r in results if r["family"] == f]) for f in families}
    for f in families:
        by[f]["tuning_hoists_for"] = [f"{g}:{s}" for g, s in tuning_hoists_for(f)]
        by[f]["own_tuning_seeds"] = settings_seeds_of(f)
    return {"families": by, "all": family_summary(results)}


def _c(cell: dict, digits: int = 2) -> str:
    if not cell or cell.get("median") is None:
        return "-"
    return f"{cell['median']:.{digits}f} ({cell['max']:.{digits}f})"


FAMILY_NAMES = {"lugre": "LuGre", "maxwell-slip": "Maxwell-slip", "elasto-plastic": "elasto-plastic",
                "dahl": "Dahl", "bliman-sorine": "Bliman-Sorine"}


def markdown(out: dict, command: str) -> str:
    """docs/evaluation/generalisation.md."""
    s = out["summary"]
    fams = list(s["families"])
    lines = [f"Made by `{command}`", "",
             f"Leave one seal family out: each family's hoists drawn on the {out['seeds']} seeds "
             f"(`ropemon.lab.generalise`; {out['per_family']} per family asked), {out['wall_s']} s. "
             "LuGre, Maxwell-slip and elasto-plastic are the population's own draws (the same hoists as "
             "population.md, the first of each law); Dahl and Bliman-Sorine are never drawn by the population: "
             "each scoring seed takes one of them from a stream of its own, and its hoist is the seed's drawn "
             "hoist with the seal replaced. Coulomb-Stribeck (a seal that holds no force at rest, refused at "
             "commissioning) is not among them."
             + (f" {out['reused']} of the present families' hoists were scored from the winds the population's "
                "run left (`--rescore`: the same hoist, noise and node), not simulated again." if out.get("reused")
                else ""), "",
             "**Which settings were chosen on which seeds.** Each hoist's own commissioning (its seal fitted on its "
             "test bed, its compliance on its commissioning wind) is chosen on no other hoist. Chosen on the "
             "population are constants shipped with the node and the station: "
             + "; ".join(SETTINGS_CHOSEN) + ". They were chosen by hand on the tuning seeds 1-20, which draw only "
             "LuGre, Maxwell-slip and elasto-plastic seals, and nothing is re-chosen per family here; "
             f"{SETTINGS_ON_FIELD_TRIP} were chosen on the field trip's named scenarios, a LuGre seal. So for "
             "Dahl and Bliman-Sorine every setting was chosen on other families' hoists (a true hold-out); for "
             "the present families their own tuning seeds were among those the settings were chosen on:", "",
             "| family | scored (asked) | seeds | not commissioned: `fit-friction` or `ropemon config` refuses "
             "| the site's check refuses the fit (Fs below Fc): scored with Fs lifted to Fc "
             "| fit-friction's check on the bed refuses the fit (worse than raw p x A, or it cannot run it; scored "
             "anyway) "
             "| node refused the config | `ropemon config` refuses the seal (scored anyway) "
             "| tuning seeds of its own among 1-20 |", "|---|---|---|---|---|---|---|---|---|"]
    for f in fams:
        c = s["families"][f]
        lines.append(f"| {FAMILY_NAMES.get(f, f)} | {c['scored']} ({len(c['seeds'])}) | "
                     f"{', '.join(map(str, c['seeds'])) or '-'} | {', '.join(map(str, c['not_commissioned'])) or 'none'} | "
                     f"{', '.join(map(str, c['lifted'])) or 'none'} | {', '.join(map(str, c['check_worse'])) or 'none'} | "
                     f"{', '.join(map(str, c['refused'])) or 'none'} | "
                     f"{', '.join(map(str, c['seal_refused'])) or 'none'} | {len(c['own_tuning_seeds'])} |")
    errs = [r for r in out["hoists"] if "error" in r]
    lines += [""] + [f"- ERROR: {scenario_name(r['family'], r['seed'])}: {r['error']}" for r in errs] + ([""] if errs else [])
    lines += ["Worst rope's RMS error, % of rated, node / raw p x A, median (max) over the family's hoists, "
              "by phase; the node is the firmware's 10 Hz frame means, raw p x A the tap pressure times the "
              "bore's area, both against the truth over the same windows:", "",
              "| family | estimator | " + " | ".join(lbl for _n, lbl in PHASE_COLUMNS) + " |",
              "|---|---|" + "---|" * len(PHASE_COLUMNS)]
    for f in [*fams, None]:
        c = s["all"] if f is None else s["families"][f]
        for e in ESTIMATORS:
            lines.append(f"| {'all' if f is None else FAMILY_NAMES.get(f, f)} | {'node' if e == 'node' else 'raw p x A'} | "
                         + " | ".join(_c(c["phases"][n][e]["rope_rms_pct"]) for n, _l in PHASE_COLUMNS) + " |")
    lines += ["", "The total's RMS error at each rest and over the wind, % of the rated total (4 x rated), "
              "median (max):", "",
              "| family | node, bottom | raw, bottom | node, top | raw, top | node, wind | raw, wind |",
              "|---|---|---|---|---|---|---|"]
    for f in [*fams, None]:
        c = s["all"] if f is None else s["families"][f]
        ph = c["phases"]
        lines.append(f"| {'all' if f is None else FAMILY_NAMES.get(f, f)} | "
                     + " | ".join(_c(ph[n][e]["total_rms_pct"]) for n in (*RESTS, WIND) for e in ESTIMATORS) + " |")
    lines += ["", f"Do no harm: at each rest, the winds where the node's total and every rope are no further from "
              f"the truth (RMS over the rest) than raw p x A's plus {DNH_MARGIN_PCT} % of rated, and the largest "
              "excess of the node's error over raw's (a rope or the total, % of rated; negative: better than raw "
              "everywhere):", "",
              "| family | hoists | bottom: winds ok | bottom: worst excess | top: winds ok | top: worst excess |",
              "|---|---|---|---|---|---|"]
    for f in [*fams, None]:
        c = s["all"] if f is None else s["families"][f]
        for key, which in (("do_no_harm", "all scored"),
                           ("do_no_harm_accepted", "those the commissioning accepts")):
            cells = []
            for rest in RESTS:
                d = c[key][rest]
                cells += [f"{d['ok']} of {d['winds']}" if d["winds"] else "-",
                          f"{d['worst_excess_pct']:+.2f} ({d['worst']})" if d["worst_excess_pct"] is not None else "-"]
            lines.append(f"| {'all' if f is None else FAMILY_NAMES.get(f, f)} | {which} | " + " | ".join(cells) + " |")
    lines += ["", "| family | seed | hoist | wind RMS node / raw | bottom: rope RMS node / raw, total node / raw "
              "| top: rope RMS node / raw, total node / raw |", "|---|---|---|---|---|---|"]
    for r in out["hoists"]:
        fam = FAMILY_NAMES.get(r["family"], r["family"])
        if "phases" not in r:
            why = ("ERROR " + r["error"] if "error" in r else "not commissioned: "
                   + r.get("not_commissioned", r.get("refused", "")))
            lines.append(f"| {fam} | {r['seed']} | {r['hoist']} | {why} | | |")
            continue
        ph = r["phases"]

        def pair(n, k):
            a, b = (ph["node"][n] or {}).get(k), (ph["raw"][n] or {}).get(k)
            return "-" if a is None or b is None else f"{a:.2f} / {b:.2f}"
        lines.append(f"| {fam} | {r['seed']} | {r['hoist']} | {pair(WIND, 'rope_rms_pct')} | "
                     f"{pair('rest-bottom', 'rope_rms_pct')}, {pair('rest-bottom', 'total_rms_pct')} | "
                     f"{pair('rest-pithead', 'rope_rms_pct')}, {pair('rest-pithead', 'total_rms_pct')} |")
    return "\n".join(lines) + "\n"


def evaluate(families, n: int, out_dir: Path | None, jobs: int, bed: dict | None, command: str, seeds: str = "scoring",
             log=None, work: Path | None = None, reuse: Path | None = None) -> dict:
    """Run and report (`--leave-one-family-out`); writes OUT/generalisation.md and .json when out_dir;
    `reuse`: a population run's directory whose winds the present families' hoists are scored from."""
    import tempfile

    from ropemon.lab.evaluate import jsonable

    pool = P.SCORING_SEEDS if seeds == "scoring" else P.TUNING_SEEDS
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="ropemon-generalise-") as tmp:
        hoists = run(families, n, work or Path(tmp), jobs, bed, log, pool, reuse)
    out = jsonable({"seeds": seeds, "per_family": n, "families": list(families), "quick": bed is not None,
                    "wall_s": round(time.monotonic() - t0, 1), "dnh_margin_pct": DNH_MARGIN_PCT,
                    "reused": sum(1 for h in hoists if "reused" in h),
                    "summary": summary(hoists, families), "hoists": hoists})
    out["markdown"] = markdown(out, command)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "generalisation.json").write_text(
            json.dumps({k: v for k, v in out.items() if k != "markdown"}, indent=1, allow_nan=False) + "\n")
        (out_dir / "generalisation.md").write_text(out["markdown"])
    return out
