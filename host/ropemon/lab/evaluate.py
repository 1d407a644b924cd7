"""`ropemon evaluate [SCENARIO ...] [--out DIR] [--json]`: every estimator against simulator truth.

For each scenario: simulate the hoist (`ropemon.lab.plant`), commission the node the
way a site would (friction fitted by `ropemon.commission.calibrate` on the noisy simulated
test bed of the scenario's own seal, as `python -m ropemon.lab.testbed --scenario`
runs it; pipe tables and the assumed oil temperature from the site description;
a failed commissioning is reported, never replaced), run the sensor stream through every estimator of
`ropemon.lab.estimators` (LuGre ones through the float reference) and through the
fixed-point firmware under the real `micropython`, and score them with
`ropemon.lab.metrics`. docs/accuracy.md explains the figures and holds the results.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ropemon.lab import estimators as E
from ropemon.lab import metrics as M
from ropemon.lab import population
from ropemon.lab.rundir import NODE_EVALUATED, RunDir, decode_frames
from ropemon.station.protocol import load_node_keys
from ropemon.station.physical import Physical

REPO = Path(__file__).resolve().parents[3]
SCENARIO_DIR = REPO / "scenarios"
FIELD_TRIP = "paper-field-trip"


# The scenarios of issue 6 that are variations of the paper's field trip, made here
# from scenarios/paper-field-trip.toml so the variation is the only difference:
# name -> (what it tests, change to the scenario document, change to its SITE.toml text or None).
def _set(path: str, value):
    def change(doc: dict) -> None:
        *keys, last = path.split(".")
        t = doc
        for k in keys:
            t = t.setdefault(k, {})
        t[last] = value
    return change


def _payload(kg: float):
    def change(doc: dict) -> None:
        loads = [ph for ph in doc["trip"]["phase"] if ph["kind"] == "load" and ph["payload_kg"] > 0]
        for ph in loads:
            ph["payload_kg"] = kg
    return change


def _other_friction(doc: dict) -> None:
    fr = doc["plant"]["friction"]
    doc["plant"]["friction"] = {"law": "coulomb-stribeck", **{k: fr[k] for k in ("Fs", "Fc", "vs", "sigma2")},
                                "v_threshold": 2e-5}


def _noisy(doc: dict) -> None:
    doc.setdefault("sensors", {}).update(pressure_noise_Pa=20e3, displacement_noise_m=4e-5, adc_noise_counts=3.0)


def _stuck(doc: dict) -> None:
    doc.setdefault("sensors", {})["fault"] = [{"kind": "stuck", "channel": "pressure", "rope": 1, "start_s": 30.0}]


def _open_loop(doc: dict) -> None:
    doc.setdefault("sensors", {})["fault"] = [{"kind": "open_loop", "channel": "pressure", "rope": 1,
                                               "start_s": 30.0}]


def _long_rest(doc: dict) -> None:
    rests = [ph for ph in doc["trip"]["phase"] if ph["kind"] == "rest"]
    rests[-1]["duration_s"] = 120.0  # the field trip's last: the empty cage at the pithead


def _quiet(doc: dict) -> None:
    doc.setdefault("sensors", {}).update(pressure_noise_Pa=1.25e3, adc_noise_counts=0.25)


def _temperature_input(text: str) -> str:
    """The site's commented-out oil temperature input, fitted."""
    if "# " + TEMPERATURE_INPUT not in text:
        raise EvaluationError(f"the site has no commented-out `{TEMPERATURE_INPUT}` to fit the input with")
    return text.replace("# " + TEMPERATURE_INPUT, TEMPERATURE_INPUT)


def _site_play(sigmas: float):
    """The site's [compliance] table with the friction observer's play (docs/commissioning.md)."""
    def change(text: str) -> str:
        table = "[compliance]\n"
        if text.count(table) != 1:
            raise EvaluationError("the site has no single [compliance] table to set the play in")
        return text.replace(table, f"{table}friction_play_sigmas = {sigmas}\n")
    return change


def duty_doc(doc: dict, trips: int = 50, seed: int = 50) -> None:
    """The scenario document's [trip] replaced by a duty cycle of `trips` winds of the field trip's
    hoist: payload 0-12 t, oil 0-40 C, short rests and loads; `seed` draws them."""
    doc.pop("trip", None)
    doc["duty"] = {"trips": trips, "payload_kg": [0.0, 12000.0], "oil_temp_C": [0.0, 40.0],
                   "rest_s": [6.0, 12.0], "load_s": [4.0, 8.0], "v_max_m_s": 10.0, "a_max_m_s2": 0.75,
                   "jerk_m_s3": 0.5, "seed": seed}


def _duty(doc: dict) -> None:
    duty_doc(doc)


VARIANTS = {
    "payload-0t": ("the field trip with the cage empty both ways", _payload(0.0), None),
    "payload-12t": ("the field trip with the rated payload (12 t)", _payload(12000.0), None),
    "oil-0C": ("oil at 0 C, the node assumes 20 C", _set("plant.oil_temp_C", 0.0), None),
    "oil-20C": ("oil at 20 C, as the node assumes", _set("plant.oil_temp_C", 20.0), None),
    "oil-40C": ("oil at 40 C, the node assumes 20 C", _set("plant.oil_temp_C", 40.0), None),
    "oil-0C-temp-input": ("oil at 0 C, node with an oil temperature input", _set("plant.oil_temp_C", 0.0),
                          _temperature_input),
    "oil-40C-temp-input": ("oil at 40 C, node with an oil temperature input", _set("plant.oil_temp_C", 40.0),
                           _temperature_input),
    "rope-length-5cm": ("rope 1 effectively 5 cm longer than the others",
                        _set("plant.ropes.offsets_m", [0.05, 0.0, 0.0, 0.0]), None),
    "pithead-long-rest": ("the field trip with the empty cage resting 120 s at the pithead, not 4 s",
                          _long_rest, None),
    "sensor-noise": ("pressure noise 20 kPa, displacement noise 40 um, ADC noise 3 counts", _noisy, None),
    "quiet-sensors": ("pressure transmitters a quarter as noisy (1.25 kPa, ADC noise 0.25 counts), "
                      "the site's play at 1.6 sigma", _quiet, _site_play(1.6)),
    "pressure-noise-drift": ("pressure transmitters 20 % noisier (6 kPa) than when the node was commissioned "
                             "(5 kPa)", _set("sensors.pressure_noise_Pa", 6e3), None),
    "stuck-sensor": ("rope 2's pressure transmitter sticks at 30 s", _stuck, None),
    "pressure-loop-open": ("rope 2's pressure loop opens (0 mA) at 30 s", _open_loop, None),
    "plant-other-friction": ("the plant's seals follow a Coulomb-Stribeck law, not LuGre", _other_friction, None),
    "duty-cycle-50": ("50 winds, payload 0-12 t, oil 0-40 C, node assumes 20 C", _duty, None),
}
# Scenarios whose commissioning wind was recorded before their sensors changed: this
# undoes the change for it (the node is commissioned as it was, then runs the wind).
COMMISSIONED_BEFORE = {"pressure-noise-drift": _set("sensors.pressure_noise_Pa", 5e3)}
# Scenarios whose seal `ropemon config` must refuse (site.seal_refusal): a Coulomb-Stribeck
# seal releases its force at standstill, which the node's LuGre does not. The figures show
# what a node forced onto such a seal would read.
REFUSAL_EXPECTED = ("plant-other-friction",)
# What `make evaluate` runs when no scenario is named.
DEFAULT_SCENARIOS = (FIELD_TRIP, *VARIANTS)
TEMPERATURE_INPUT = "temperature = { counts_at_0C = 16000.0, counts_per_C = 320.0 }"
FIRMWARE = "firmware"


@dataclass
class Case:
    """One simulated scenario, commissioned and estimated: what the metrics need."""

    name: str
    sample_hz: int
    frame_hz: int
    rated_n: float
    truth_n: np.ndarray                 # (samples, ropes) true rope-end tensions
    phase: np.ndarray                   # (samples,) index into metrics.PHASES
    excluded: np.ndarray                # (samples,) within SHOCK_HOLD_S after a shock
    steady: np.ndarray | None = None    # (samples,) payload not being changed (for the pithead total)
    estimates: dict[str, np.ndarray] = field(default_factory=dict)   # name -> (samples, ropes) N
    firmware_n: np.ndarray | None = None   # (frames, ropes) window means, N
    payload_kg: np.ndarray | None = None   # (samples,) payload in the cage (empty-cage pithead rest)
    commissioning: dict = field(default_factory=dict)  # the fit the node was commissioned from, problems
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)  # full compensation fed with truths
    notes: list[str] = field(default_factory=list)
    physical: dict = field(default_factory=dict)  # the commissioned config's physical section
    frames: list = field(default_factory=list)    # the firmware's decoded data frames, in order

    @property
    def window(self) -> int:
        return self.sample_hz // self.frame_hz

    @property
    def t_s(self) -> np.ndarray:
        return np.arange(len(self.truth_n)) / self.sample_hz


# ---------------------------------------------------------------- scoring


def score(case: Case) -> dict:
    """All figures of one case: per estimator whole wind, by phase, pithead, alarms."""
    out: dict = {"estimators": {}, "notes": list(case.notes), "commissioning": dict(case.commissioning),
                 "samples": len(case.truth_n), "sample_hz": case.sample_hz,
                 "excluded_samples": int(case.excluded.sum())}
    for name, est in case.estimates.items():
        fig = M.evaluate_estimate(est, case.truth_n, case.rated_n, case.phase, case.excluded, case.steady,
                                  case.payload_kg)
        fig["alarms"] = M.alarm_assessment(est, case.truth_n, case.excluded, case.window,
                                           frame_s=case.window / case.sample_hz)
        out["estimators"][name] = fig
    if case.firmware_n is not None:
        out["estimators"][FIRMWARE] = score_frames(case)
    out["diagnostics"] = {name: M.evaluate_estimate(est, case.truth_n, case.rated_n, case.phase, case.excluded,
                                                    case.steady, case.payload_kg)
                          for name, est in case.diagnostics.items()}
    return out


def frame_view(case: Case, per_sample: np.ndarray) -> np.ndarray:
    """Per-sample values averaged over the node's frame windows."""
    return M.window_means(per_sample, case.window)


def score_frames(case: Case) -> dict:
    """The firmware's frame means against truth averaged over the same windows,
    and against the float reference of the same compensation (`vs_reference_*`)."""
    w = case.window
    assert case.firmware_n is not None
    n = min(len(case.firmware_n), len(case.truth_n) // w)
    fw = case.firmware_n[:n]
    truth = frame_view(case, case.truth_n)[:n]
    phase = case.phase[: n * w: w]
    excluded = M.window_means(case.excluded.astype(float), w)[:n] > 0
    steady = None if case.steady is None else M.window_means(case.steady.astype(float), w)[:n] == 1.0
    payload = None if case.payload_kg is None else M.window_means(case.payload_kg, w)[:n]
    fig = M.evaluate_estimate(fw, truth, case.rated_n, phase, excluded, steady, payload)
    fig["alarms"] = M.alarm_assessment(fw, truth, excluded, 1, frame_s=w / case.sample_hz)
    fig["frames"] = int(n)
    # the firmware ran with the commissioned config, the same the float reference used
    ref = case.estimates.get(E.FULL_COMPENSATION)
    if ref is not None:
        diff = (fw - frame_view(case, ref)[:n]) / case.rated_n * 100.0
        both = np.isfinite(diff)  # a window where the reference gives no tension (failed loop) is not compared
        fig["vs_reference_max_pct"] = float(np.max(np.abs(diff[both]))) if both.any() else float("nan")
        fig["vs_reference_rms_pct"] = float(np.sqrt(np.mean(diff[both] ** 2))) if both.any() else float("nan")
        fig["vs_reference_frames"] = int(both.all(axis=1).sum())
    return fig


# ---------------------------------------------------------------- report


TARGETS = {
    "pithead_total_pct": 0.3,   # |error| of the total at the pithead rest, % of true total
    "rope_rms_pct": 1.0,        # whole wind, each rope, % of rated
    "rope_peak_pct": 3.0,
    "vs_reference_max_pct": 0.05,
}


def _finite(x) -> bool:
    return x is not None and math.isfinite(x)


def _fmt(x, digits=2) -> str:
    if not _finite(x):
        return "-"
    return f"{x:.{digits}f}"


def _mark(value, limit) -> str:
    if not _finite(value):
        return ""
    return " ok" if abs(value) <= limit else " **FAIL**"


def _commissioned(sc: dict) -> str:
    """The summary's commissioning cell: the fitted sigma0, or FAILED loudly."""
    c = sc.get("commissioning") or {}
    if not c:
        return "-"
    if c.get("refusal_expected") and not c.get("problems"):
        return ("refused by `ropemon config`, as expected (see notes)" if c.get("seal_refused")
                else "**NOT refused** (see notes)")
    if not c.get("ok"):
        return "**FAILED** (see notes)"
    k = c.get("hydraulic_compliance_m_per_Pa") or []
    k_txt = f", k {min(k) * 1e9:.3f}-{max(k) * 1e9:.3f} um/kPa" if k else ""
    if k:
        fb = c.get("bounce_hz")
        k_txt += f", bounce {fb:.2f} Hz" if fb is not None else ", bounce not measured"
    return f"sigma0 {c['sigma0_N_per_m']:.4g} N/m fitted{k_txt}"


def _pithead(f: dict, which: str) -> str:
    v = f.get(f"pithead_{which}_total_pct")
    return f"{_fmt(v)}{_mark(v, TARGETS['pithead_total_pct'])}"


def summary_table(results: dict) -> str:
    """One line per scenario: the full compensation against the targets."""
    full = E.FULL_COMPENSATION
    lines = [f"| scenario | commissioning | raw pithead empty % | `{full}` pithead empty % "
             f"| `{full}` pithead as arrived % | `{full}` rope RMS % "
             f"| `{full}` rope peak % | best simpler (rope RMS %) | firmware vs float max % "
             f"| `{full}` false @8 % / missed @12 %: frames; operator alarms |",
             "|---|---|---:|---:|---:|---:|---:|---|---:|---|"]
    for name, sc in results["scenarios"].items():
        if "error" in sc:
            lines.append(f"| {name} | not evaluated: {sc['error']} |||||||||")
            continue
        est = sc["estimators"]
        f = est.get(full, {})
        best = _best_simpler(est)
        fw = est.get(FIRMWARE, {})
        al = f.get("alarms", {})
        lines.append(
            f"| {name} | {_commissioned(sc)} | {_fmt(est.get('raw', {}).get('pithead_empty_total_pct'))} "
            f"| {_pithead(f, 'empty')} | {_pithead(f, 'arrival')} "
            f"| {_fmt(f.get('rope_rms_pct'))}{_mark(f.get('rope_rms_pct'), TARGETS['rope_rms_pct'])} "
            f"| {_fmt(f.get('rope_peak_pct'))}{_mark(f.get('rope_peak_pct'), TARGETS['rope_peak_pct'])} "
            f"| {'-' if best is None else f'`{best[0]}` {_fmt(best[1])}'}"
            f"{'' if best is None or not _finite(f.get('rope_rms_pct')) else ' ' + _verdict(f['rope_rms_pct'], best[1])} "
            f"| {'not run' if FIRMWARE not in est else _fmt(fw.get('vs_reference_max_pct'), 4)}"
            f"{_mark(fw.get('vs_reference_max_pct'), TARGETS['vs_reference_max_pct'])} "
            f"| {al.get('8', {}).get('false', '-')} / {al.get('12', {}).get('missed', '-')} "
            f"of {al.get('8', {}).get('frames', '-')}; "
            f"{al.get('8', {}).get('false_alarms', '-')} / {al.get('12', {}).get('missed_alarm_frames', '-')} |")
    lines += ["", "Pithead totals are the total-load error in % of the true total: *empty* over the pithead "
              "rest with the cage empty (after unloading: the paper's 185.4 kN measurement, and what "
              "`pithead_total_pct` reports), *as arrived* over the rest before the payload is first "
              "changed (the field trip's loaded cage; `pithead_total_pct` where a scenario has no "
              "empty-cage pithead rest, as `pithead_total_basis` says). `-`: the scenario has no such rest.",
              "", "Alarms, with one rope truly 8 % (false) or 12 % (missed) off the mean: first the frames "
              "whose 10 % flag is wrong, then what the operator would see, the host's own debounced "
              "deviation alarm (`ropemon.station.alarms`: raised after 0.5 s over 2 frames, cleared after 2 s "
              "under 8 %): false raises, and frames where the same debounce on the true deviation holds "
              "the alarm and the estimate's does not."]
    return "\n".join(lines)


def markdown(results: dict) -> str:
    """The results as Markdown tables: a summary, then one section per scenario."""
    lines = ["## Summary", ""]
    failed = commissioning_failed(results)
    if failed:
        lines += [f"**COMMISSIONING FAILED for {', '.join(failed)}**: the node could not be commissioned "
                  "from a fit of the scenario's own seal (see the scenario's notes); their figures are "
                  "not evidence.", ""]
    lines += [summary_table(results), "", "## Per scenario", ""]
    for name, sc in results["scenarios"].items():
        lines += [f"### {name}", ""]
        if "error" in sc:
            lines += [f"Not evaluated: {sc['error']}", ""]
            continue
        for note in sc.get("notes", []):
            lines.append(f"- {note}")
        if sc.get("notes"):
            lines.append("")
        lines += ["| estimator | rope RMS % | rope peak % | total RMS % | pithead empty % "
                  "| pithead as arrived % | false @8 % | missed @12 % | false alarms @8 % "
                  "| missed alarm frames @12 % |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for est, f in sc["estimators"].items():
            al = f.get("alarms", {})
            fa = al.get("8", {})
            mi = al.get("12", {})
            lines.append(
                f"| {est} | {_fmt(f['rope_rms_pct'])}{_mark(f['rope_rms_pct'], TARGETS['rope_rms_pct'])} "
                f"| {_fmt(f['rope_peak_pct'])}{_mark(f['rope_peak_pct'], TARGETS['rope_peak_pct'])} "
                f"| {_fmt(f['total_rms_pct'])} "
                f"| {_pithead(f, 'empty')} | {_pithead(f, 'arrival')} "
                f"| {fa.get('false', '-')}/{fa.get('frames', '-')} | {mi.get('missed', '-')}/{mi.get('frames', '-')} "
                f"| {fa.get('false_alarms', '-')} | {mi.get('missed_alarm_frames', '-')} |")
        lines.append("")
        lines += ["Rope RMS % by phase (worst rope; `-` = phase absent):", "",
                  "| estimator | " + " | ".join(M.PHASES) + " |",
                  "|---|" + "---:|" * len(M.PHASES)]
        for est, f in sc["estimators"].items():
            lines.append(f"| {est} | " + " | ".join(_fmt(f["by_phase"][p]["rope_rms_pct"]) for p in M.PHASES) + " |")
        lines.append("")
        fw = sc["estimators"].get(FIRMWARE)
        if fw and "vs_reference_max_pct" in fw:
            v = fw["vs_reference_max_pct"]
            lines += [f"Fixed-point firmware vs float reference (frame means): max {_fmt(v, 4)} % of rated"
                      f"{_mark(v, TARGETS['vs_reference_max_pct'])}.", ""]
        if sc.get("diagnostics"):
            lines += ["Diagnostics: the full compensation given what a node cannot know "
                      "(not estimators; they locate the error):", "",
                      "| fed with | rope RMS % | rope peak % | pithead empty % | pithead as arrived % |",
                      "|---|---:|---:|---:|---:|"]
            for d, f in sc["diagnostics"].items():
                lines.append(f"| {d} | {_fmt(f['rope_rms_pct'])} | {_fmt(f['rope_peak_pct'])} "
                             f"| {_fmt(f.get('pithead_empty_total_pct'))} | {_fmt(f.get('pithead_arrival_total_pct'))} |")
            lines.append("")
        best = _best_simpler(sc["estimators"])
        if best is not None:
            full = sc["estimators"][E.FULL_COMPENSATION]["rope_rms_pct"]
            verdict = {"(tie)": f"ties (within {TIE_PCT} %) with", "(full wins)": "beats"}.get(
                _verdict(full, best[1]), "does NOT beat")
            lines += [f"`{E.FULL_COMPENSATION}` ({_fmt(full)} %) {verdict} the best simpler estimator "
                      f"`{best[0]}` ({_fmt(best[1])} %) on whole-wind rope RMS.", ""]
    return "\n".join(lines)


def commissioning_failed(results: dict) -> list[str]:
    """Scenarios whose node could not be commissioned from a fit of their own seal, or whose
    seal `ropemon config` refused unexpectedly or failed to refuse (REFUSAL_EXPECTED)."""
    out = []
    for name, sc in results["scenarios"].items():
        c = sc.get("commissioning") or {}
        if c.get("problems") or bool(c.get("seal_refused")) != bool(c.get("refusal_expected")):
            out.append(name)
        elif not c.get("ok", True) and not c.get("refusal_expected"):
            out.append(name)
    return out


TIE_PCT = 0.01  # RMS figures closer than this (% of rated) are a tie


def _verdict(full_pct: float, best_pct: float) -> str:
    if abs(full_pct - best_pct) < TIE_PCT:
        return "(tie)"
    return "(full wins)" if full_pct < best_pct else "**(simpler wins)**"


def _best_simpler(estimators: dict):
    if E.FULL_COMPENSATION not in estimators or not _finite(estimators[E.FULL_COMPENSATION]["rope_rms_pct"]):
        return None
    simpler = [(n, f["rope_rms_pct"]) for n, f in estimators.items()
               if n in E.ESTIMATORS and n != E.FULL_COMPENSATION and _finite(f["rope_rms_pct"])]
    return min(simpler, key=lambda x: x[1]) if simpler else None


def plot(case: Case, out_dir: Path) -> list[Path]:
    """PNG plots of one case: tensions over the wind and the error of each estimator."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    t = case.t_s
    paths = []
    shown = [n for n in ("raw", "stribeck+loss", "lugre-const+loss", E.FULL_COMPENSATION) if n in case.estimates]
    fig, axes = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    axes[0].plot(t, case.truth_n.sum(axis=1) / 1e3, "k", lw=1.5, label="truth")
    for n in shown:
        axes[0].plot(t, case.estimates[n].sum(axis=1) / 1e3, lw=0.8, label=n)
    if case.firmware_n is not None:
        tf = (np.arange(len(case.firmware_n)) + 0.5) * case.window / case.sample_hz
        axes[0].plot(tf, case.firmware_n.sum(axis=1) / 1e3, ".", ms=2, label=FIRMWARE)
    axes[0].set_ylabel("total load, kN")
    axes[0].legend(fontsize=8, loc="upper left")
    for n in shown:
        axes[1].plot(t, (case.estimates[n][:, 0] - case.truth_n[:, 0]) / case.rated_n * 100, lw=0.8, label=n)
    ymin, ymax = axes[1].get_ylim()
    axes[1].fill_between(t, ymin, ymax, where=case.excluded, color="0.85", label="after shock (excluded)")
    axes[1].set_ylabel("rope 1 error, % of rated")
    axes[1].set_xlabel("time, s")
    axes[1].legend(fontsize=8, loc="lower left")
    fig.suptitle(case.name)
    fig.tight_layout()
    p = out_dir / f"{case.name}-tension.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    return paths


def bar_plot(results: dict, out_dir: Path) -> Path:
    """Whole-wind rope RMS of every estimator, one group per scenario."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in (*E.ESTIMATORS, FIRMWARE)]
    scen = [s for s, r in results["scenarios"].items() if "estimators" in r]
    fig, ax = plt.subplots(figsize=(13, 4 + 0.1 * len(scen)))
    width = 0.8 / max(1, len(scen))
    x = np.arange(len(names))
    for k, s in enumerate(scen):
        vals = [results["scenarios"][s]["estimators"].get(n, {}).get("rope_rms_pct") for n in names]
        vals = [v if _finite(v) else np.nan for v in vals]
        ax.bar(x + k * width, vals, width, label=s)
    ax.axhline(TARGETS["rope_rms_pct"], color="r", lw=0.8, ls="--", label="target")
    ax.set_xticks(x + 0.4 - width / 2, names, rotation=45, ha="right")
    ax.set_yscale("log")
    ax.set_ylabel("whole-wind rope RMS error, % of rated")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    p = out_dir / "rms-by-estimator.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p


# ---------------------------------------------------------------- the pipeline


class EvaluationError(RuntimeError):
    """A scenario that could not be evaluated; the message says which step and why."""


def variant(name: str):
    """(what it tests, change to the scenario document, change to its SITE.toml text or None) of a
    field-trip variant: one of VARIANTS or a drawn hoist of the population (`population-SEED`)."""
    if name in VARIANTS:
        return VARIANTS[name]
    seed = population.seed_of(name)
    if seed is None:
        return None
    h = population.draw(seed)
    return (f"drawn hoist (seed {seed}): {h.describe()}", population.change_doc(h), population.change_site(h))


def scenario_path(name: str) -> Path:
    """A scenario name (scenarios/NAME.toml or a variant, see `variant`) or a path to a TOML file."""
    if variant(name) is not None:
        return SCENARIO_DIR / f"{FIELD_TRIP}.toml"
    p = Path(name)
    if p.suffix == ".toml" and p.exists():
        return p
    p = SCENARIO_DIR / f"{name}.toml"
    if not p.exists():
        known = sorted(q.stem for q in SCENARIO_DIR.glob("*.toml") if q.stem != "paper-site")
        raise EvaluationError(f"scenario {name!r}: no {p.relative_to(REPO) if p.is_relative_to(REPO) else p} "
                              "and no variant of that name; "
                              f"known: {', '.join(known + list(VARIANTS))}")
    return p


def scenario_doc(name: str, work: Path) -> tuple[dict, Path]:
    """The scenario document to simulate and the path its relative names resolve against."""
    from ropemon.station import files

    path = scenario_path(name)
    doc = files.read_toml(path, "scenario", files.MAX_SCENARIO_TOML, EvaluationError)
    if variant(name) is None:
        return doc, path
    _what, change, site_edit = variant(name)
    change(doc)
    doc["name"] = name
    if site_edit is not None:
        site_path = path.parent / doc["site"]
        site_text = files.read_text(site_path, "SITE.toml", files.MAX_SITE_TOML, EvaluationError)
        try:
            text = site_edit(site_text)
        except (EvaluationError, ValueError) as e:
            raise EvaluationError(f"{site_path}: {e}") from None
        # the copy lives in `work`: its friction and compliance files must still be found
        text = text.replace('file = "', f'file = "{site_path.parent}/')
        work.mkdir(parents=True, exist_ok=True)
        (work / "site-variant.toml").write_text(text)
        doc["site"] = str((work / "site-variant.toml").resolve())
    return doc, path


def _run_step(what: str, cmd: list[str], timeout_s: float) -> str:
    import subprocess

    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise EvaluationError(f"{what}: timed out after {timeout_s:.0f} s: {' '.join(cmd)}") from None
    if r.returncode != 0:
        tail = (r.stderr or r.stdout).strip().splitlines()[-5:]
        raise EvaluationError(f"{what}: exit {r.returncode}: " + " | ".join(tail))
    return r.stdout


def simulate(name: str, out_dir: Path, seed: int, change=None) -> None:
    """Run the plant (ropemon.lab.plant's Python API, as `ropemon simulate` does) into out_dir;
    `change(doc)` edits the scenario document first."""
    from ropemon.lab.plant.cli import summarize
    from ropemon.lab.plant.output import write_outputs
    from ropemon.lab.plant.run import simulate as run_plant
    from ropemon.lab.plant.scenario import ScenarioError, build

    doc, path = scenario_doc(name, out_dir)
    if change is not None:
        change(doc)
    try:
        sc = build(doc, path, seed)
        res = run_plant(sc)
    except (ScenarioError, FloatingPointError) as e:
        raise EvaluationError(f"simulate {name}: {e}") from None
    write_outputs(res, out_dir, summarize(res))

# Test-bed procedure of the commissioning: ropemon.lab.testbed's defaults (6 pressure
# levels, 12 speeds each way, then slow pre-sliding reversals stretched to the seal's vs).
BED_DEFAULTS: dict = {}
# `--quick`: 3 levels, 6 speeds, short holds, still with the pre-sliding reversals
# (sigma0 is fitted, as for the docs): a smoke run, not for the docs.
BED_QUICK = {"pressures_MPa": (3.0, 7.0, 11.0), "speeds_m_s": (0.001, 0.002, 0.004, 0.008, 0.016, 0.03),
             "hold_s": 0.6}
SIGMA0_FITTED = ("fitted", "fitted sigma0, default sigma1")  # calibrate.fit's presliding sources
REFUSED = "the node refuses the commissioned config"


def _toml(value) -> str:
    """A TOML value (the scalars, lists and tables a [plant.friction] table holds)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    raise EvaluationError(f"plant.friction: cannot write {value!r} as TOML")


def write_seal(plant_friction: dict, path: Path) -> Path:
    """The scenario's hidden seal as a scenario file holding only [plant.friction], so the
    bed reads it through `ropemon.lab.testbed.scenario_seal` like `python -m ropemon.lab.testbed --scenario`."""
    import tomllib

    text = "[plant.friction]\n" + "".join(f"{k} = {_toml(v)}\n" for k, v in plant_friction.items())
    if tomllib.loads(text)["plant"]["friction"] != plant_friction:
        raise EvaluationError("plant.friction: does not survive writing as TOML")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def fit_plant_seal(plant_friction: dict, work: Path, seed: int, bed: dict | None = None) -> dict:
    """Fit friction as a site would: the scenario's (hidden) seal on the simulated test bed
    of `python -m ropemon.lab.testbed --scenario` (reversals stretched to the seal's vs), noisy
    records to CSV, `ropemon fit-friction`'s fit. Cached in `work` per seal, seed and bed."""
    import fcntl
    import hashlib

    from ropemon.commission import calibrate
    from ropemon.lab import testbed
    from ropemon.lab.plant import friction as plant_friction_module
    from ropemon.lab.plant.scenario import ScenarioError

    bed = {**BED_DEFAULTS, **(bed or {})}
    # the cache is keyed by the bed's, the seal's and the fitter's source too: an edit there refits
    code = [hashlib.sha256(Path(str(m.__file__)).read_bytes()).hexdigest()
            for m in (calibrate, testbed, plant_friction_module)]
    key = json.dumps([plant_friction, seed, bed, code], sort_keys=True)
    cache = work / f"friction-{hashlib.sha256(key.encode()).hexdigest()[:12]}.json"
    work.mkdir(parents=True, exist_ok=True)
    # scenarios run in parallel processes share a seal (the field trip's variants): the first fits it,
    # the others wait for its cache
    with open(cache.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if cache.exists():
            return json.loads(cache.read_text())
        seal = write_seal(plant_friction, cache.with_suffix(".seal.toml"))
        try:
            params, law_factory = testbed.scenario_seal(seal)
        except ScenarioError as e:
            raise EvaluationError(f"test bed: {e}") from None
        period_s = testbed.presliding_period_s(params, pressures_MPa=bed.get("pressures_MPa", testbed.PRESSURES_MPA))
        data = testbed.run(params, seed=seed, law_factory=law_factory, presliding_period_s=period_s, **bed)
        csv_path = cache.with_suffix(".csv")
        testbed.write_csv(csv_path, data)
        try:
            doc, _levels, warnings = calibrate.fit(calibrate.read_csv(csv_path), source=str(csv_path))
        except calibrate.FitError as e:
            raise EvaluationError(f"fit-friction on the simulated test bed: {e}") from None
        doc["bed"] = {"presliding_period_s": period_s, "warnings": warnings}
        tmp = cache.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(doc, indent=1))
        os.replace(tmp, cache)
    return doc


def commissioning_problems(fit: dict, physical: dict) -> list[str]:
    """Why the node could not be commissioned from this fit (empty when it can): sigma0 not
    fitted (fit-friction fell back to its default), or the config the node refuses."""
    from ropemon.commission.nodejson import make_node_json

    problems = []
    src = fit.get("presliding", {}).get("source", "?")
    if src not in SIGMA0_FITTED:
        problems.append(f"sigma0 NOT fitted on the test bed ({src}): sigma0 = {fit.get('sigma0', float('nan')):.4g} "
                        f"N/m is fit-friction's default, not this seal's")
    try:
        make_node_json(physical)
    except ValueError as e:
        problems.append(f"{REFUSED}: {e}")
    return problems


# `physical` keys the evaluation commissions itself (never taken from the simulator's node.json)
COMMISSIONED_KEYS = ("friction", "loss", "hydraulic_compliance_m_per_Pa", "pressure_noise_Pa",
                     "displacement_noise_m", "bounce_hz")
# `physical` keys only the site description gives (the simulator's truth must not supply them)
SITE_KEYS = ("start_depth_m",)
# `physical` keys that define what the sensor stream's counts mean (docs/config.md)
SENSOR_KEYS = ("ropes", "sample_hz", "adc_bits", "cylinder_area_m2", "pressure_channels",
               "displacement_channels", "speed_m_per_pulse", "hall_marks_m", "battery_V_per_count",
               "temperature")


# The commissioning wind: the scenario's hoist wound once more, recorded as a site
# records one after installing the node (no sensor faults, other noise), from which
# `ropemon fit-compliance` measures each cylinder's hydraulic compliance.
COMMISSIONING_SEED_OFFSET = 1000


def _commissioning_wind_doc(doc: dict) -> None:
    import tomllib

    doc.get("sensors", {}).pop("fault", None)
    if "duty" in doc:  # one wind of the field trip's, on the same plant
        del doc["duty"]
        doc["trip"] = tomllib.loads((SCENARIO_DIR / f"{FIELD_TRIP}.toml").read_text())["trip"]


def fit_compliance(name: str, physical: dict, work: Path, seed: int) -> dict:
    """Simulate the scenario's commissioning wind into work/commissioning-wind and fit k there."""
    from ropemon.commission import compliance

    def wind(doc: dict) -> None:
        _commissioning_wind_doc(doc)
        if name in COMMISSIONED_BEFORE:
            COMMISSIONED_BEFORE[name](doc)

    cw = work / "commissioning-wind"
    simulate(name, cw, seed + COMMISSIONING_SEED_OFFSET, wind)
    recs = RunDir(cw).records
    try:
        return compliance.fit(physical, recs).as_dict()
    except compliance.ComplianceError as e:
        return {"error": str(e)}


def _site_physical(truth_meta: dict, friction: dict, compliance: dict | None = None) -> dict:
    """The node's `physical` section from the scenario's site description, a friction fit
    and (optionally) a compliance fit."""
    from ropemon.commission.site import load_site, physical_from_site

    site_file = truth_meta.get("site_file")
    if not site_file:
        raise EvaluationError(f"scenario {truth_meta.get('scenario')}: no site file: not a hoist scenario")
    site = load_site(site_file)
    physical = physical_from_site(site, friction, compliance, refuse_unheld=False)  # refusal: build_case
    # The sensor stream was made with the simulator's node config: how counts map to
    # physical units must be the same. What the simulator sets per run is taken from it, as
    # an installer would set it; what the site says (SITE_KEYS) never comes from the simulator.
    plant_ph = truth_meta.get("node_physical") or {}
    for k, v in plant_ph.items():
        if k in COMMISSIONED_KEYS or k in SITE_KEYS or physical.get(k) == v:
            continue
        if k in SENSOR_KEYS:
            raise EvaluationError(f"site {site_file}: `{k}` differs from the config the simulator's sensors use")
        physical[k] = v
    return physical


def firmware_frames(physical: dict, rsens: Path, work: Path, node_json: Path | None = None,
                    frames_name: str = "frames.bin") -> list:
    """The data frames of the fixed-point firmware under `micropython` (`ropemon replay`)
    on a config (default: the commissioned one `build_case` wrote, `node-evaluated.json`),
    decoded, in order."""
    node_json = node_json or work / NODE_EVALUATED
    frames_bin = work / frames_name
    _run_step("firmware (ropemon replay)", [sys.executable, "-m", "ropemon.cli", "replay", str(rsens),
                                            "--out", str(frames_bin), "--config", str(node_json)],
              timeout_s=3600)
    frames, counts = decode_frames(frames_bin, load_node_keys(node_json))
    bad = {k: v for k, v in counts.as_dict().items() if k != "frames_ok" and v}
    if bad:
        raise EvaluationError(f"firmware frames did not decode cleanly: {bad}")
    if frames and [f.seq for f in frames] != list(range(frames[0].seq, frames[0].seq + len(frames))):
        raise EvaluationError("firmware frames: sequence numbers not consecutive")
    return frames


def frame_means_n(frames) -> np.ndarray:
    """Each frame's rope mean tensions [frame, rope] in N; NaN for a rope the frame marks
    absent (no healthy sample in its window), so it is neither scored nor compared."""
    return np.array([[np.nan if r.absent else float(r.mean_n) for r in f.ropes] for f in frames],
                    float).reshape(len(frames), -1)


def _standstill(meta: dict, t_s: np.ndarray) -> np.ndarray:
    """Samples of the scenario's first phase if it is a rest (hoist and load still), else the first 0.5 s."""
    phases = meta.get("phases") or []
    if phases and phases[0]["kind"] == "rest":
        return (t_s >= phases[0]["t0_s"]) & (t_s < phases[0]["t1_s"])
    return t_s < 0.5


def scoring_masks(truth, truth_n: np.ndarray, hz: int, rated_n: float, shaft_depth_m: float):
    """(phase, excluded, steady, payload_kg) per sample of a wind's `truth.npz` arrays, as
    every figure is scored: the phase of the wind, the samples after a shock, the samples
    whose payload is not being changed, the payload."""
    k = len(truth_n)
    # phases of the wind are the drive's (wheel) motion; the cage bounces on its ropes after a stop
    phase = M.classify_phases(truth["cage_depth_m"][:k], truth["wheel_speed_m_s"][:k],
                              truth["wheel_accel_m_s2"][:k], shaft_depth_m)
    t_s = np.arange(k) / hz
    excluded = M.shock_mask(t_s, M.detect_shocks(t_s, truth_n, rated_n))
    payload = np.asarray(truth["payload_kg"], float)[:k]
    steady = np.concatenate([[True], np.diff(payload) == 0])
    return phase, excluded, steady, payload


def build_case(name: str, work: Path, seed: int = 1, firmware: bool = True, bed: dict | None = None,
               diagnostics: bool = True) -> Case:
    """Simulate, commission and run every estimator on one scenario (with `diagnostics`, also the
    runs fed with what the node cannot know, `_add_diagnostics`)."""
    from ropemon.commission import reference

    sim = work / "sim"
    simulate(name, sim, seed)
    run = RunDir(work)
    meta, truth = run.meta, run.truth
    if meta.get("rig") != "hoist":
        raise EvaluationError(f"scenario {name}: rig {meta.get('rig')!r}, evaluate needs a hoist wind")
    plant_friction = meta["scenario_doc"]["plant"]["friction"]
    fit = fit_plant_seal(plant_friction, work.parent, seed, bed)
    physical = _site_physical(meta, fit)
    hyd = fit_compliance(name, physical, work, seed)
    if "error" not in hyd:  # the site names the compliance file: ropemon config takes it in
        physical = _site_physical(meta, fit, hyd)
    problems = commissioning_problems(fit, physical)
    if "error" in hyd:
        problems.append(f"fit-compliance on the commissioning wind: {hyd['error']}")
    phys = Physical.from_dict(physical)
    rated = phys.rated_rope_tension_N
    hz, recs = run.sample_hz, run.records[: run.length]
    truth_n = np.asarray(truth["tension_N"], float)[: len(recs)]
    phase, excluded, steady, payload = scoring_masks(truth, truth_n, hz, rated, phys.hall_marks_m[-1])
    case = Case(name=Path(name).stem, sample_hz=hz, frame_hz=phys.frame_hz, rated_n=rated,
                truth_n=truth_n, phase=phase, excluded=excluded, steady=steady, payload_kg=payload,
                physical=physical)
    from ropemon.commission.site import seal_refusal

    refusal = seal_refusal(fit)
    case.commissioning = {
        "ok": not problems and not refusal, "problems": problems,
        "seal_refused": refusal, "refusal_expected": Path(name).stem in REFUSAL_EXPECTED,
        "sigma0_N_per_m": fit.get("sigma0"), "sigma1_N_s_per_m": fit.get("sigma1"),
        "presliding_source": fit.get("presliding", {}).get("source"),
        "presliding_period_s": fit.get("bed", {}).get("presliding_period_s"),
        "fit_warnings": fit.get("bed", {}).get("warnings", []),
        "hydraulic_compliance_m_per_Pa": hyd.get("hydraulic_compliance_m_per_Pa"),
        "pressure_noise_Pa": hyd.get("pressure_noise_Pa"),
        "displacement_noise_m": hyd.get("displacement_noise_m"),
        "bounce_hz": hyd.get("bounce_hz"),
    }
    for problem in problems:
        case.notes.append(f"**COMMISSIONING FAILED**: {problem}")
    if refusal:
        case.notes.append(f"**`ropemon config` refuses this seal**"
                          f"{' (as this scenario expects)' if case.commissioning['refusal_expected'] else ''}: "
                          f"{refusal}. The figures below are those of a node commissioned from the fit anyway.")
    elif case.commissioning["refusal_expected"]:
        case.notes.append("**COMMISSIONING FAILED**: `ropemon config` accepted a seal this scenario expects it "
                          "to refuse")
    if "error" not in hyd:
        case.notes.append(
            "hydraulic compliance from `ropemon fit-compliance` on a commissioning wind (the same "
            f"plant, seed {seed + COMMISSIONING_SEED_OFFSET}, no sensor faults): k "
            + ", ".join(f"{k * 1e9:.4f}" for k in hyd["hydraulic_compliance_m_per_Pa"])
            + f" um/kPa, pressure noise {hyd['pressure_noise_Pa'] / 1e3:.2f} kPa, displacement noise "
            + f"{hyd['displacement_noise_m'] * 1e6:.1f} um, bounce at the arrival "
            + (f"{hyd['bounce_hz']:.2f} Hz" if hyd.get("bounce_hz") is not None
               else "not measured (the node's default)"))
    oil = np.asarray(truth["oil_temp_C"], float)
    case.notes.append(
        f"node {'NOT ' if problems or refusal else ''}commissioned from a fit of this scenario's own seal on the "
        f"simulated test bed{' (the float estimators below use the refused fit as it is)' if problems or refusal else ''}: "
        f"sigma0 {fit.get('sigma0', float('nan')):.4g} N/m, sigma1 {fit.get('sigma1', float('nan')):.4g} N s/m "
        f"({fit.get('presliding', {}).get('source', '?')}); oil {oil.min():.0f}..{oil.max():.0f} C actual, "
        f"{phys.oil_temp_assumed_C:g} C assumed, temperature input "
        f"{'fitted' if phys.temperature else 'none'}")

    p_cal = float(np.mean(fit.get("pressure_range_MPa", [6.0, 6.0])))
    variants = {
        "lugre-p": E.no_loss_physical(physical),
        "lugre-const+loss": E.lugre_const_physical(physical, p_cal),
        "lugre-const": E.lugre_const_physical(E.no_loss_physical(physical), p_cal),
    }
    full = reference.compensate(physical, recs)
    case.estimates[E.FULL_COMPENSATION] = full.tension_n
    for est_name, ph in variants.items():
        case.estimates[est_name] = reference.compensate(ph, recs).tension_n
    area = np.asarray(phys.cylinder_area_m2, float)
    sig = E.Signals(full.p_pa, full.v_m_s, full.loss_n / area)
    still = _standstill(meta, np.arange(len(truth_n)) / hz)
    deadband = E.deadband_from_standstill(full.v_m_s[still])
    case.notes.append(f"static laws: velocity dead band {deadband * 1e3:.2f} mm/s "
                      f"({E.DEADBAND_SIGMAS:g} x the velocity-estimate RMS over {still.sum() / hz:.1f} s of standstill)")
    for est_name in E.ESTIMATORS:
        if est_name.partition("+")[0] in E.STATIC_FRICTION_LAWS:
            est = E.static_estimate_n(est_name, physical, sig, deadband)
            case.estimates[est_name] = np.where(full.good, est, np.nan)
    case.estimates = {n: case.estimates[n] for n in E.ESTIMATORS}
    refused = any(pr.startswith(REFUSED) for pr in problems)
    if not refused:  # the commissioned config, for the firmware and the studies (`ropemon study`)
        from ropemon.commission.nodejson import make_node_json, write_node_json

        write_node_json(work / NODE_EVALUATED, make_node_json(physical, **run.identity))
    if firmware and not refused:
        case.frames = firmware_frames(physical, run.sensors_path, work)
        case.firmware_n = frame_means_n(case.frames)
    elif firmware:
        case.notes.append("**firmware NOT run**: the node refuses the commissioned config (above); "
                          "no fixed-point vs float check for this scenario")
    if diagnostics:
        _add_diagnostics(case, physical, meta, truth, recs)
    return case


IDEAL_DISPLACEMENT_SPAN_M = 0.02  # +-20 mm over the same counts: ~2 um per count
DIRECT_DIAGNOSTIC = "ideal displacement driving the observer (no compliance)"


def ideal_displacement(physical: dict, recs: np.ndarray, x_true_m: np.ndarray,
                       span_m: float = IDEAL_DISPLACEMENT_SPAN_M) -> tuple[dict, np.ndarray]:
    """A config and stream whose displacement channels read the true piston position
    without noise, on a channel of +-span_m about the piston's middle position (a
    diagnostic: what a finer sensor would give)."""
    import copy

    ph = copy.deepcopy(physical)
    out = recs.copy()
    n = int(ph["ropes"])
    for i in range(n):
        dc = ph["displacement_channels"][i]
        x = np.asarray(x_true_m[: len(recs), i], float)
        mid = 0.5 * (x.min() + x.max())
        dc["range_m"] = [mid - span_m, mid + span_m]
        frac = (x - mid + span_m) / (2 * span_m)
        counts = dc["counts_lo"] + frac * (dc["counts_hi"] - dc["counts_lo"])
        out[:, n + i] = np.clip(np.round(counts), 0, 0xFFFE).astype(out.dtype)
    return ph, out


NO_STROKES_DIAGNOSTIC = "balancing strokes not tracked (stroke_sigmas 0)"


def _add_diagnostics(case: Case, physical: dict, meta: dict, truth, recs: np.ndarray) -> None:
    """The full compensation fed with what the node cannot know: the plant's own friction
    parameters, a noiseless finer displacement, or both, and that displacement driving the
    observer without the compliance; and the node as commissioned but without its
    balancing-stroke tracking. They show where the error comes from."""
    from ropemon.commission import reference
    from ropemon.lab.plant.friction import LuGre, from_table

    law = from_table(dict(meta["scenario_doc"]["plant"]["friction"]), "plant.friction")
    ideal_ph, ideal_recs = ideal_displacement(physical, recs, truth["piston_x_m"])
    phys = Physical.from_dict(physical)
    site_span = 0.5 * abs(np.diff(phys.displacement_channels[0].range_m)[0])
    runs = {"noiseless displacement at the site's resolution":
            ideal_displacement(physical, recs, truth["piston_x_m"], site_span),
            "ideal displacement": (ideal_ph, ideal_recs)}
    # the same finer, noiseless channel driving the observer directly (no compliance, the
    # position low-pass at the velocity filter's cutoff, a play of one count's noise): what
    # the node would do if its displacement channel were good enough to follow every stroke
    direct = {k: v for k, v in ideal_ph.items() if k not in ("hydraulic_compliance_m_per_Pa", "pressure_noise_Pa")}
    direct.update(friction_cutoff_hz=phys.velocity_cutoff_hz, displacement_noise_m=0.0,
                  friction_play_sigmas=1.0)
    runs[DIRECT_DIAGNOSTIC] = (direct, ideal_recs)
    runs[NO_STROKES_DIAGNOSTIC] = (dict(physical, stroke_sigmas=0.0), recs)
    if isinstance(law, LuGre):
        runs["plant friction"] = (dict(physical, friction=law.as_fit()), recs)
        runs["plant friction, ideal displacement"] = (dict(ideal_ph, friction=law.as_fit()), ideal_recs)
    for name, (ph, rr) in runs.items():
        case.diagnostics[f"{E.FULL_COMPENSATION}, {name}"] = reference.compensate(ph, rr).tension_n


def jsonable(x):
    """NaN (a phase or figure that does not exist in a scenario) as null: strict JSON."""
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, np.generic):
        return jsonable(x.item())
    return x


# ---------------------------------------------------------------- command


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenarios", nargs="*", metavar="SCENARIO",
                   help="scenario names (scenarios/NAME.toml, or a field-trip variant: "
                        + ", ".join(VARIANTS) + ") or TOML paths; default: paper-field-trip and every variant")
    p.add_argument("--out", type=Path, help="write results.json, accuracy.md and PNG plots here")
    p.add_argument("--json", action="store_true", help="print the results as one JSON object")
    p.add_argument("--seed", type=int, default=1, help="simulator and test-bed noise seed (default 1)")
    p.add_argument("--quick", action="store_true",
                   help="a short friction test bed (smoke runs and tests, not for the docs)")
    p.add_argument("--no-firmware", action="store_true",
                   help="skip the fixed-point run under micropython (float estimators only)")
    p.add_argument("--population", type=int, metavar="N",
                   help="evaluate N drawn hoists (ropemon.lab.population) instead of the named scenarios")
    p.add_argument("--seeds", choices=("scoring", "tuning"), default="scoring",
                   help="population seeds: scoring (101-200, the reported figures: no setting was chosen "
                        "on them) or tuning (1-20, where settings are chosen); default scoring")
    p.add_argument("--jobs", type=int, default=2, help="scenarios or population winds run at a time (processes; default 2)")
    p.add_argument("--faults", action="store_true",
                   help="with --population: also run each hoist with one drawn fault and score the station's "
                        "alarms against the Targets (faults.md, faults.json)")
    p.add_argument("--rescore", action="store_true",
                   help="with --population --faults --out OUT: score the station's alarms as they are now on the "
                        "winds a run left in OUT/population (no simulation); writes faults.md and faults.json only; "
                        "with --leave-one-family-out --out OUT: the present families' hoists scored from the winds "
                        "OUT/population holds (the held-out families' simulated)")
    p.add_argument("--leave-one-family-out", type=int, metavar="N",
                   help="N hoists of each seal family (population.LAWS and HELD_OUT_LAWS) on the --seeds, node "
                        "and raw p x A by phase, do no harm at the rests (ropemon.lab.generalise; "
                        "generalisation.md, generalisation.json)")
    p.add_argument("--family", action="append", metavar="NAME",
                   help="with --leave-one-family-out: only this seal family (repeatable); default all")
    p.add_argument("--duty-cycles", type=int, default=0, metavar="K",
                   help=f"with --faults: the first K hoists also through a {population.DUTY_TRIPS}-wind duty cycle "
                        "with one rope creeping (the adjustment advisory); default 0")


def default_scenarios() -> list[str]:
    return list(DEFAULT_SCENARIOS)


#: Scenarios run without the diagnostics (six more float-reference runs, here over 50 winds);
#: the single-wind scenarios locate the error.
NO_DIAGNOSTICS = frozenset({"duty-cycle-50"})
# Run first when the scenarios run in parallel: one of them takes about as long as all the others on
# one worker, so started last it would run alone at the end.
LONG_SCENARIOS = frozenset({"duty-cycle-50"})


def evaluate_one(name: str, work: Path, seed: int = 1, firmware: bool = True,
                 plots: Path | None = None, bed: dict | None = None) -> dict:
    """One scenario's results (`build_case`, `score`, its plots); an error is reported in them."""
    t0 = time.monotonic()
    try:
        case = build_case(name, work / Path(name).stem, seed, firmware, bed,
                          diagnostics=name not in NO_DIAGNOSTICS)
        if variant(name) is not None:
            case.notes.insert(0, f"{FIELD_TRIP} variant: {variant(name)[0]}")
        res = score(case)
        if plots is not None:
            plot(case, plots)
    except (EvaluationError, OSError, ValueError, KeyError) as e:
        res = {"error": f"{type(e).__name__}: {e}" if not isinstance(e, EvaluationError) else str(e)}
    res["wall_s"] = round(time.monotonic() - t0, 1)
    return res


def evaluate(names: list[str], work: Path, seed: int = 1, firmware: bool = True,
             plots: Path | None = None, log=None, bed: dict | None = None, jobs: int = 1) -> dict:
    """Evaluate each scenario, `jobs` at a time (processes), the results in the order of `names`;
    one that fails is reported with its error, the others go on."""
    results: dict = {"scenarios": {}, "seed": seed}

    def done(name: str, res: dict) -> None:
        if log:
            c = res.get("commissioning", {})
            status = ("ERROR " + res["error"] if "error" in res else
                      "COMMISSIONING FAILED: " + "; ".join(c["problems"] or ["see the notes"])
                      if name in commissioning_failed({"scenarios": {name: res}}) else
                      "done (`ropemon config` refuses the seal, as expected)" if c.get("seal_refused") else "done")
            log(f"{name}: {status} ({res['wall_s']} s)")

    by_name: dict[str, dict] = {}
    if jobs <= 1 or len(names) <= 1:
        for name in names:
            by_name[name] = evaluate_one(name, work, seed, firmware, plots, bed)
            done(name, by_name[name])
    else:
        from concurrent.futures import ProcessPoolExecutor, as_completed
        with ProcessPoolExecutor(max_workers=jobs) as ex:
            first = sorted(names, key=lambda n: Path(n).stem not in LONG_SCENARIOS)  # stable: the rest in order
            futs = {ex.submit(evaluate_one, name, work, seed, firmware, plots, bed): name for name in first}
            for fut in as_completed(futs):
                name = futs[fut]
                by_name[name] = fut.result()
                done(name, by_name[name])
    for name in names:
        results["scenarios"][Path(name).stem] = by_name[name]
    return results


def _command_line(args: argparse.Namespace, names: list[str]) -> str:
    opts = [f"--out {args.out}", f"--seed {args.seed}"]
    opts += ["--quick"] * bool(args.quick) + ["--no-firmware"] * bool(args.no_firmware)
    return " ".join(["ropemon evaluate", *names, *opts])


def run_population(args: argparse.Namespace) -> int:
    """`--population N`: N drawn hoists from the scoring (or tuning) seeds, scored."""
    pool = population.SCORING_SEEDS if args.seeds == "scoring" else population.TUNING_SEEDS
    if not 1 <= args.population <= len(pool):
        print(f"ropemon evaluate: --population must be 1..{len(pool)} for the {args.seeds} seeds", file=sys.stderr)
        return 2
    seeds = pool[: args.population]
    if args.duty_cycles and not args.faults:
        print("ropemon evaluate: --duty-cycles needs --faults", file=sys.stderr)
        return 2
    if not 0 <= args.duty_cycles <= args.population:
        print(f"ropemon evaluate: --duty-cycles must be 0..{args.population} (the hoists run)", file=sys.stderr)
        return 2
    if args.faults and args.no_firmware:
        print("ropemon evaluate: --faults scores the station on the node's frames: it needs the firmware",
              file=sys.stderr)
        return 2
    log = (lambda s: print(s, file=sys.stderr, flush=True))
    t0 = time.monotonic()
    if args.rescore:
        return rescore_population(args, seeds, log, t0)
    with tempfile.TemporaryDirectory(prefix="ropemon-population-") as tmp:
        work = args.out / "population" if args.out else Path(tmp)
        winds = population.run(seeds, work, args.jobs, not args.no_firmware,
                               BED_QUICK if args.quick else None, log, args.faults, seeds[: args.duty_cycles])
    out = jsonable({"population": population.summary(winds, "node"),
                    "baseline": population.summary(winds, "baseline"),
                    "by_law": population.by_law(winds), "seeds": args.seeds, "quick": bool(args.quick),
                    "wall_s": round(time.monotonic() - t0, 1), "winds": winds})
    if args.faults:
        out["targets"] = jsonable(population.targets_summary(winds))
    md = population.markdown(out)
    command = (f"ropemon evaluate --population {args.population} --seeds {args.seeds}"
               f"{' --quick' if args.quick else ''}")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "population.json").write_text(json.dumps(out, indent=1, allow_nan=False) + "\n")
        (args.out / "population.md").write_text(f"Made by `{command}`\n\n" + md)
        if args.faults:
            fault_cmd = command + " --faults" + (f" --duty-cycles {args.duty_cycles}" if args.duty_cycles else "")
            (args.out / "faults.md").write_text(population.targets_markdown(out, fault_cmd))
            (args.out / "faults.json").write_text(json.dumps({k: out[k] for k in ("targets", "seeds", "wall_s")}
                                                             | {"winds": [{"seed": w["seed"],
                                                                           "targets": w.get("targets")}
                                                                          for w in winds]},
                                                             indent=1, allow_nan=False) + "\n")
    if args.json:
        json.dump(out, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(md)
        if args.faults:
            print(population.targets_markdown(out, "ropemon evaluate " + " ".join(sys.argv[2:])))
    return 1 if out["population"]["errors"] else 0


def rescore_population(args: argparse.Namespace, seeds, log, t0: float) -> int:
    """`--rescore`: the Targets of the winds already run in OUT/population, scored again."""
    if not (args.faults and args.out):
        print("ropemon evaluate: --rescore needs --faults and the --out of the run to score again", file=sys.stderr)
        return 2
    work = args.out / "population"
    if not work.is_dir():
        print(f"ropemon evaluate: --rescore: {work}: no population run there", file=sys.stderr)
        return 2
    winds = []
    for s in seeds:
        winds.append(population.rescore_targets(s, work))
        log(f"{population.PREFIX}{s}: " + ("ERROR " + winds[-1]["error"] if "error" in winds[-1] else "scored")
            + f" ({winds[-1]['wall_s']} s)")
    out = jsonable({"targets": population.targets_summary(winds), "seeds": args.seeds,
                    "wall_s": round(time.monotonic() - t0, 1), "winds": winds})
    command = (f"ropemon evaluate --population {args.population} --seeds {args.seeds} --faults --rescore "
               f"--out {args.out}")
    (args.out / "faults.json").write_text(json.dumps(out, indent=1, allow_nan=False) + "\n")
    md = population.targets_markdown(out, command, f"ropemon evaluate --population {args.population} --seeds "
                                               f"{args.seeds} --faults --out {args.out}")
    (args.out / "faults.md").write_text(md)
    if args.json:
        json.dump(out, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(md)
    return 1 if any("error" in w for w in winds) else 0


def run_generalisation(args: argparse.Namespace) -> int:
    """`--leave-one-family-out N`: ropemon.lab.generalise."""
    from ropemon.lab import generalise

    families = args.family or list(generalise.FAMILIES)
    unknown = [f for f in families if f not in generalise.FAMILIES]
    if unknown or args.leave_one_family_out < 1 or args.population is not None or args.no_firmware:
        print("ropemon evaluate: --leave-one-family-out N (N >= 1, with the firmware, not with --population); "
              f"--family one of {', '.join(generalise.FAMILIES)}", file=sys.stderr)
        return 2
    if args.rescore and not args.out:
        print("ropemon evaluate: --leave-one-family-out --rescore needs the --out of a population run", file=sys.stderr)
        return 2
    command = (f"ropemon evaluate --leave-one-family-out {args.leave_one_family_out} --seeds {args.seeds}"
               + "".join(f" --family {f}" for f in args.family or ()) + (" --quick" if args.quick else "")
               + (f" --rescore --out {args.out}" if args.rescore else ""))
    out = generalise.evaluate(families, args.leave_one_family_out, args.out, args.jobs,
                              BED_QUICK if args.quick else None, command, args.seeds,
                              lambda s: print(s, file=sys.stderr, flush=True),
                              args.out / "generalisation" if args.out else None,
                              args.out / "population" if args.rescore else None)
    if args.json:
        json.dump({k: v for k, v in out.items() if k != "markdown"}, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(out["markdown"])
    return 1 if out["summary"]["all"]["errors"] else 0


def run(args: argparse.Namespace) -> int:
    if args.leave_one_family_out is not None:
        return run_generalisation(args)
    if args.population is not None:
        return run_population(args)
    names = args.scenarios or default_scenarios()
    if not names:
        print("ropemon evaluate: no scenarios found in scenarios/", file=sys.stderr)
        return 2
    try:
        for n in names:
            scenario_path(n)
    except EvaluationError as e:
        print(f"ropemon evaluate: {e}", file=sys.stderr)
        return 2
    log = (lambda s: print(s, file=sys.stderr, flush=True))
    with tempfile.TemporaryDirectory(prefix="ropemon-evaluate-") as tmp:
        work = args.out / "runs" if args.out else Path(tmp)
        results = evaluate(names, work, args.seed, not args.no_firmware, args.out, log,
                           BED_QUICK if args.quick else None, args.jobs)
        results["quick"] = bool(args.quick)
    results = jsonable(results)
    md = markdown(results)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "results.json").write_text(json.dumps(results, indent=1, allow_nan=False) + "\n")
        (args.out / "accuracy.md").write_text(
            f"Made by `{_command_line(args, names)}`\n\n" + md)
        bar_plot(results, args.out)
    if args.json:
        json.dump(results, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(md)
    failed = commissioning_failed(results)
    if failed:
        print(f"ropemon evaluate: COMMISSIONING FAILED for {', '.join(failed)} (see their notes)", file=sys.stderr)
    return 1 if failed or any("error" in r for r in results["scenarios"].values()) else 0
