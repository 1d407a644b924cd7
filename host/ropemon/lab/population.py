"""A population of simulated hoists for `ropemon evaluate --population`: drawn, commissioned, scored.

Each seed draws one hoist from documented ranges (`RANGES`, docs/simulator.md
"Population"), built on the paper's field trip (scenarios/paper-field-trip.toml and
its site): the seals' law and parameters (one seal type per hoist, each rope's seal
scattered about it), rope length offsets, cylinder bore, hose lengths, oil
temperature and payload. The evaluation then commissions it as a site would (its
seal type on the test bed, `ropemon fit-friction`; `ropemon fit-compliance` on an
ordinary wind of the same hoist) and runs the node on a wind.

Settings are chosen on `TUNING_SEEDS` and figures reported on `SCORING_SEEDS`, which
no setting was chosen on.

The *baseline* is the node before it followed the sliding its displacement channels prove
(slide following off) with the station before the band (the deviation alarm alone),
commissioned the same way; the *node* is both as they are now.

Scoring of one wind (`run_wind`), from the node's frames as the host decodes them:
- accuracy: the firmware's frame means against the true rope tensions averaged over
  the same windows (worst rope RMS and peak, % of rated; the empty-cage pithead total);
- alarms: the host's own `AlarmEngine` on the frames. A rope truly beyond the
  deviation limit for `SILENT_MIN_S` or more must raise at least DEVIATION POSSIBLE
  within that episode, or the wind is *silent*. A raise on a rope whose true deviation
  is within `FALSE_BELOW` is a *false warning*; the *warning share* is the part of the
  time a deviation alarm or warning stands on ropes truly within `FALSE_BELOW` (a warning
  raised once that never clears counts once, but stands all the time). Both on the wind as it is and with a
  deviation of `SUPERPOSED` superposed on each rope in turn, both signs (the force
  carried as pressure, as `metrics.alarm_assessment` does).
"""
from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass

import numpy as np

from ropemon.lab.rundir import RunDir
from ropemon.lab.studies.stroke_events import follow_figures

TUNING_SEEDS = tuple(range(1, 21))
SCORING_SEEDS = tuple(range(101, 201))
PREFIX = "population-"

LAWS = ("lugre", "maxwell-slip", "elasto-plastic")
# Seal families `draw` never picks (so the tuning and scoring hoists stay as they are): a
# leave-one-family-out evaluation gives a drawn hoist one of these by seal_table(law, h.draws, ...).
HELD_OUT_LAWS = ("dahl", "bliman-sorine")
# The ranges each hoist is drawn from (uniform unless `log`: uniform in the logarithm).
RANGES = {
    "force_level": (0.25, 1.0, "log"),     # seal forces x this, relative to the field trip's (worn) seal
    "slope_ratio": (0.5, 1.5, "lin"),      # pressure slopes of the force lines x this, besides the level
    "vs_scale": (0.5, 2.0, "log"),         # Stribeck velocity
    "stiffness_scale": (0.5, 2.0, "log"),  # pre-sliding stiffness (sigma0, element stiffnesses)
    "element_spread": (0.5, 2.0, "log"),   # Maxwell-slip: each element's break displacement x this
    "z_ba_fraction": (0.2, 0.8, "lin"),    # elasto-plastic: the purely elastic share of pre-sliding
    "rope_force_scale": (0.85, 1.15, "lin"),   # each rope's seal about the type's
    "offset_m": (-0.010, 0.010, "lin"),    # each rope's effective length offset at the start
    "groove_creep": (-1.25e-5, 1.25e-5, "lin"),  # each rope's extra pay-out per metre wound: +-10 mm per wind
    "bore_m": (0.090, 0.125, "lin"),       # cylinder bore, the same on every rope
    "hose_scale": (0.6, 1.6, "lin"),       # each rope's pipe lengths to its tap
    "oil_temp_C": (0.0, 40.0, "lin"),      # the node assumes the site's 20 C
    "payload_kg": (0.0, 12000.0, "lin"),   # taken on at the bottom, unloaded at the pithead
}
ROPES = 4

SILENT_MIN_S = 2.0
DEVIATION_LIMIT = 0.10
FALSE_BELOW = 0.08
SUPERPOSED = 0.12


@dataclass(frozen=True)
class Hoist:
    """One drawn hoist: what the plant is, and nothing the node may know."""

    seed: int
    law: str
    friction: dict            # the plant's [plant.friction] table (with each rope's force_scale)
    offsets_m: tuple
    groove_creep: tuple
    bore_m: float
    hose_scale: tuple
    oil_temp_C: float
    payload_kg: float
    draws: dict               # the raw factors, for the report

    @property
    def name(self) -> str:
        return f"{PREFIX}{self.seed}"

    def describe(self) -> str:
        d = self.draws
        return (f"{self.law} seal x{d['force_level']:.2f} (ropes " + ", ".join(f"{s:.2f}" for s in
                                                                             self.friction["force_scale"])
                + f"), ropes part " + ", ".join(f"{c * 806e3:+.1f}" for c in self.groove_creep)
                + f" mm per wind, bore {self.bore_m * 1e3:.0f} mm, oil {self.oil_temp_C:.0f} C, "
                f"payload {self.payload_kg / 1e3:.1f} t")


def seed_of(name: str) -> int | None:
    """The seed of a population scenario name (`population-N`), else None."""
    m = re.fullmatch(re.escape(PREFIX) + r"(\d+)", name)
    return int(m.group(1)) if m else None


def _uniform(rng: np.random.Generator, key: str, size=None):
    lo, hi, kind = RANGES[key]
    if kind == "log":
        return np.exp(rng.uniform(math.log(lo), math.log(hi), size))
    return rng.uniform(lo, hi, size)


def _scale_line(line: dict, level: float, slope_ratio: float = 1.0) -> dict:
    return {"intercept": line["intercept"] * level, "slope": line.get("slope", 0.0) * level * slope_ratio}


def seal_table(law: str, draws: dict, rope_scale) -> dict:
    """The plant's friction table for a law (LAWS or HELD_OUT_LAWS) from its example
    (`plant.friction.example_table`), scaled by the draws. A held-out law's own parameters come
    from the draws no other law of the hoist uses: Dahl's exponent 1-2 from z_ba_fraction's,
    Bliman-Sorine's eta (x0.5-2 of 0.1) and ef (x0.5-2, over stiffness_scale) from element_spread's."""
    from ropemon.lab.plant.friction import example_table

    t = example_table(law)
    level, ratio = draws["force_level"], draws["slope_ratio"]
    out = dict(t)
    for k in ("Fs", "Fc", "sigma2"):
        if k in t:
            out[k] = _scale_line(t[k], level, ratio)
    if "vs" in t:
        out["vs"] = {"intercept": t["vs"]["intercept"] * draws["vs_scale"],
                     "slope": t["vs"].get("slope", 0.0) * draws["vs_scale"]}
    stiff = level * draws["stiffness_scale"]  # the pre-sliding distance moves with stiffness_scale only
    if "sigma0" in t:
        out["sigma0"] = t["sigma0"] * stiff
    if "sigma1" in t:
        out["sigma1"] = t["sigma1"] * math.sqrt(stiff)
    if law == "maxwell-slip":  # each element's break displacement scattered about the example's
        out["k"] = [k * stiff / d for k, d in zip(t["k"], draws["element_spread"])]
    if law == "elasto-plastic":
        out["z_ba_fraction"] = round(draws["z_ba_fraction"], 3)
    if law == "dahl":          # z_ba_fraction's uniform 0.2-0.8 as an exponent 1-2
        out["exponent"] = round(1.0 + (draws["z_ba_fraction"] - 0.2) / 0.6, 3)
    if law == "bliman-sorine":  # lengths scattered as Maxwell-slip's breaks, ef moving with stiffness_scale
        spread = draws["element_spread"]
        out["eta"] = round(t["eta"] * spread[0], 4)
        out["ef"] = float(f"{t['ef'] * spread[1] / draws['stiffness_scale']:.4e}")
    out["force_scale"] = [round(float(s), 4) for s in rope_scale]
    return out


def draw(seed: int) -> Hoist:
    """The hoist of one seed (reproducible: the same seed gives the same hoist)."""
    rng = np.random.default_rng([seed, 0x0E5A1])
    law = LAWS[int(rng.integers(len(LAWS)))]
    draws = {k: float(_uniform(rng, k)) for k in ("force_level", "slope_ratio", "vs_scale", "stiffness_scale",
                                                   "bore_m", "oil_temp_C", "payload_kg", "z_ba_fraction")}
    draws["element_spread"] = [float(x) for x in _uniform(rng, "element_spread", 4)]
    rope_scale = _uniform(rng, "rope_force_scale", ROPES)
    offsets = _uniform(rng, "offset_m", ROPES)
    hoses = _uniform(rng, "hose_scale", ROPES)
    creep = _uniform(rng, "groove_creep", ROPES)
    return Hoist(seed=seed, law=law, friction=seal_table(law, draws, rope_scale),
                 offsets_m=tuple(round(float(o), 5) for o in offsets),
                 groove_creep=tuple(float(f"{c:.3e}") for c in creep), bore_m=round(draws["bore_m"], 4),
                 hose_scale=tuple(round(float(h), 3) for h in hoses), oil_temp_C=round(draws["oil_temp_C"], 1),
                 payload_kg=round(draws["payload_kg"], -1), draws=draws)


def change_doc(h: Hoist):
    """The change to the field trip's scenario document that makes it this hoist."""
    def change(doc: dict) -> None:
        plant = doc["plant"]
        plant["friction"] = dict(h.friction)
        plant["ropes"]["offsets_m"] = list(h.offsets_m)
        plant["ropes"]["groove_creep"] = list(h.groove_creep)
        plant["oil_temp_C"] = h.oil_temp_C
        loads = [ph for ph in doc["trip"]["phase"] if ph["kind"] == "load" and ph["payload_kg"] > 0]
        for ph in loads:
            ph["payload_kg"] = h.payload_kg
    return change


def change_site(h: Hoist):
    """The change to the site description (SITE.toml text) that makes it this hoist: what a
    site would write of its own hoist (bore, hoses); the seal and offsets are not in it."""
    def change(text: str) -> str:
        text, n = re.subn(r"(?m)^(bore_m\s*=\s*)[0-9.eE+-]+", lambda m: f"{m.group(1)}{h.bore_m}", text)
        if n != 1:
            raise ValueError("the site has no single [cylinders] bore_m to set")
        blocks = text.split("[[pipes]]")
        if len(blocks) != ROPES + 1:
            raise ValueError(f"the site has {len(blocks) - 1} [[pipes]] tables, not {ROPES}")
        for i in range(ROPES):
            head, sep, rest = blocks[i + 1].partition("fittings")
            head = re.sub(r"length_m\s*=\s*([0-9.eE+-]+)",
                          lambda m: f"length_m = {float(m.group(1)) * h.hose_scale[i]:.3f}", head)
            blocks[i + 1] = head + sep + rest
        return "[[pipes]]".join(blocks)
    return change


# ---------------------------------------------------------------- faults

# Each scoring hoist is also run with one drawn fault (`draw_fault`), a class of FAULT_CLASSES
# and its size and onset from FAULT_RANGES (uniform unless `log`). The draw is sized about the
# alarm's threshold, so that some faults cross it within the wind and some do not; whether one
# did is read from the faulted run's truth (`fault_truth`), never from the draw.
FAULT_CLASSES = ("stroke_offset", "stroke_creep", "valve_closed", "leak", "seized_seal")
DUTY_CLASS = "creep_duty"    # unequal rope creep across a duty cycle (`draw_duty_fault`)
FAULT_RANGES = {
    # stroke_offset: the rope's length offset puts its piston this far short of its stroke margin
    # at its closest predicted approach through the wind (negative: that far into the margin)
    "stroke_gap_m": (-0.006, 0.008, "lin"),
    # stroke_creep: the piston starts this far short of its margin ...
    "creep_start_gap_m": (0.006, 0.030, "lin"),
    # ... and the rope's groove creep through the wind is set to bring it this far short at the end
    "creep_end_gap_m": (-0.008, 0.008, "lin"),
    "valve_at_s": (0.0, 125.0, "lin"),          # a stop valve closed at this time (the run is 128 s)
    "leak_rate_L_min": (0.02, 0.5, "log"),
    "leak_at_s": (0.0, 10.0, "lin"),            # before the wind starts: a whole wind follows
    "seize_factor": (2.0, 50.0, "log"),         # the seized seal's forces x this
    "seize_at_s": (0.0, 60.0, "lin"),
    # creep_duty: the rope creeps so that its piston would reach its margin after this many winds
    "duty_winds_to_margin": (20.0, 90.0, "lin"),
}
DUTY_TRIPS = 50
# The duty cycle's solver steps (docs/simulator.md; BDF2), as scenarios/fault-stroke-limit.toml: the
# creeping rope's growing imbalance makes the pistons stick and slip as the cage is unloaded at the
# pithead, which the field trip's 5 ms steps under-resolve (the linearised step runs away: seed
# 101's wind 15 at 5 ms, a cavity at -1.3 MPa); at 2.5 ms the 50 winds run through.
DUTY_STEPS = {"step_s": 0.0025, "bounce_rad_per_step": 0.05, "max_step_s": 0.01}
VALVE_SIDES = ("manifold", "cylinder")
OIL_LOSS_TARGET_L_MIN = 0.1     # the target: oil loss of this much or more alarmed within one wind


@dataclass(frozen=True)
class FaultDraw:
    """One hoist's drawn fault: what the plant does, as scenario tables (docs/simulator.md)."""

    seed: int
    kind: str                 # one of FAULT_CLASSES, or DUTY_CLASS
    rope: int                 # from 1; 0: the manifold (a leak of the connecting assembly)
    params: dict              # the drawn values (FAULT_RANGES' keys), end ("retracted"/"extended"), side
    faults: tuple = ()        # the plant's [[faults]] tables
    offsets_m: tuple | None = None      # plant.ropes.offsets_m in place of the hoist's
    groove_creep: tuple | None = None   # plant.ropes.groove_creep in place of the hoist's

    def describe(self) -> str:
        p = self.params
        where = "the manifold" if self.rope == 0 else f"rope {self.rope}"
        if self.kind == "stroke_offset":
            return (f"stroke limit by offset: rope {self.rope}'s piston {p['stroke_gap_m'] * 1e3:+.1f} mm from its "
                    f"{p['end']} margin at its closest")
        if self.kind == "stroke_creep":
            return (f"stroke limit by creep: rope {self.rope}'s piston from {p['creep_start_gap_m'] * 1e3:.1f} mm "
                    f"to {p['creep_end_gap_m'] * 1e3:+.1f} mm of its {p['end']} margin through the wind")
        if self.kind == "valve_closed":
            return f"valve closed ({p['side']} side) on rope {self.rope} at {p['valve_at_s']:.0f} s"
        if self.kind == "leak":
            return f"leak {p['leak_rate_L_min']:.3f} L/min from {where} at {p['leak_at_s']:.0f} s"
        if self.kind == "seized_seal":
            return f"seal seized x{p['seize_factor']:.1f} on rope {self.rope} at {p['seize_at_s']:.0f} s"
        return (f"rope {self.rope} creeping {self.faults[0]['mm_per_wind'][self.rope - 1]:+.2f} mm per wind "
                f"({p['end']} margin in about {p['duty_winds_to_margin']:.0f} winds)")


def _fault_uniform(rng: np.random.Generator, key: str) -> float:
    lo, hi, kind = FAULT_RANGES[key]
    if kind == "log":
        return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    return float(rng.uniform(lo, hi))


def site_stroke(site_path=None) -> tuple[float, float]:
    """(stroke_m, stroke_margin_m) of the field trip's site ([cylinders]; the margin's default 0.01 m)."""
    import tomllib
    from pathlib import Path

    path = Path(site_path) if site_path else Path(__file__).resolve().parents[3] / "scenarios" / "paper-site.toml"
    cyl = tomllib.loads(path.read_text())["cylinders"]
    if isinstance(cyl, list):
        cyl = cyl[0]
    return float(cyl["stroke_m"]), float(cyl.get("stroke_margin_m", 0.01))


# the wind of the field trip: the wheel winds this much rope (808 m to 2 m)
WOUND_M = 806.0


def _spread(rope: int, shift: float) -> np.ndarray:
    """Per-rope length offsets that move `rope`'s piston by -shift and each other's by +shift/3,
    each within 2/3 of the shift (the pistons sit at the mean offset minus each rope's)."""
    d = np.full(ROPES, -2.0 * shift / 3.0)
    d[rope] = 2.0 * shift / 3.0
    return d


def predicted_x(h: Hoist) -> tuple[np.ndarray, np.ndarray]:
    """The pistons' positions (m from mid-stroke) the hoist's own offsets and groove creep put them
    at, at the start and at the end of the wind, ignoring the load and what the seals hold."""
    d = np.asarray(h.offsets_m, float)
    c = np.asarray(h.groove_creep, float)
    x0 = d.mean() - d
    return x0, x0 + (c - c.mean()) * WOUND_M


def draw_fault(seed: int, hoist: Hoist | None = None) -> FaultDraw:
    """The drawn fault of one seed's hoist (reproducible: the same seed, the same fault)."""
    h = hoist or draw(seed)
    rng = np.random.default_rng([seed, 0xFA17])
    kind = FAULT_CLASSES[int(rng.integers(len(FAULT_CLASSES)))]
    rope = int(rng.integers(ROPES))          # from 0 here
    sign = 1.0 if rng.random() < 0.5 else -1.0   # +1: the extended end (x > 0), -1: the retracted
    end = "extended" if sign > 0 else "retracted"
    stroke, margin = site_stroke()
    edge = stroke / 2 - margin               # the margin's inner edge, from mid-stroke
    x0, x1 = predicted_x(h)
    params: dict = {}
    if kind == "stroke_offset":
        gap = _fault_uniform(rng, "stroke_gap_m")
        closest = max(sign * x0[rope], sign * x1[rope])
        shift = -sign * (edge - gap - closest)   # move the piston by -shift
        offsets = np.asarray(h.offsets_m, float) + _spread(rope, shift)
        params = {"stroke_gap_m": round(gap, 5), "end": end}
        return FaultDraw(seed, kind, rope + 1, params, (), tuple(round(float(o), 5) for o in offsets), None)
    if kind == "stroke_creep":
        g0, g1 = _fault_uniform(rng, "creep_start_gap_m"), _fault_uniform(rng, "creep_end_gap_m")
        shift0 = -sign * (edge - g0 - sign * x0[rope])
        offsets = np.asarray(h.offsets_m, float) + _spread(rope, shift0)
        # the travel toward the end the hoist's own creep leaves to make up
        travel = (g0 - g1) - sign * (x1[rope] - x0[rope])
        # groove creep moves the pistons the other way: by + the spread over the wound length
        creep = np.asarray(h.groove_creep, float) + _spread(rope, sign * travel) / WOUND_M
        params = {"creep_start_gap_m": round(g0, 5), "creep_end_gap_m": round(g1, 5), "end": end}
        return FaultDraw(seed, kind, rope + 1, params, (), tuple(round(float(o), 5) for o in offsets),
                         tuple(float(f"{c:.4e}") for c in creep))
    if kind == "valve_closed":
        side = VALVE_SIDES[int(rng.integers(len(VALVE_SIDES)))]
        at = round(_fault_uniform(rng, "valve_at_s"), 1)
        params = {"valve_at_s": at, "side": side}
        return FaultDraw(seed, kind, rope + 1, params,
                         ({"kind": "valve_closed", "rope": rope + 1, "at_s": at, "side": side},))
    if kind == "leak":
        where = int(rng.integers(ROPES + 1))     # 0: the manifold
        rate, at = round(_fault_uniform(rng, "leak_rate_L_min"), 4), round(_fault_uniform(rng, "leak_at_s"), 1)
        params = {"leak_rate_L_min": rate, "leak_at_s": at}
        return FaultDraw(seed, kind, where, params,
                         ({"kind": "leak", "rope": where, "rate_L_min": rate, "at_s": at},))
    factor, at = round(_fault_uniform(rng, "seize_factor"), 2), round(_fault_uniform(rng, "seize_at_s"), 1)
    params = {"seize_factor": factor, "seize_at_s": at}
    return FaultDraw(seed, kind, rope + 1, params,
                     ({"kind": "seized_seal", "rope": rope + 1, "factor": factor, "at_s": at},))


def draw_duty_fault(seed: int, hoist: Hoist | None = None) -> FaultDraw:
    """The creep of one seed's hoist across a duty cycle of DUTY_TRIPS winds: one rope creeps
    (slips on the wheel) so that its piston's rest position would reach its margin after a
    drawn number of winds; the hoist's own groove creep (which parts the ropes up and back down)
    is kept."""
    h = hoist or draw(seed)
    rng = np.random.default_rng([seed, 0xD07])
    rope = int(rng.integers(ROPES))
    sign = 1.0 if rng.random() < 0.5 else -1.0
    winds = _fault_uniform(rng, "duty_winds_to_margin")
    stroke, margin = site_stroke()
    x0, _ = predicted_x(h)
    gap = (stroke / 2 - margin) - sign * x0[rope]       # from its rest position to its margin
    # a rope lengthening by L moves its piston by -3L/4 (the others by +L/4)
    mm = np.zeros(ROPES)
    mm[rope] = -sign * gap / winds * 4.0 / 3.0 * 1e3
    params = {"duty_winds_to_margin": round(winds, 1), "end": "extended" if sign > 0 else "retracted"}
    return FaultDraw(seed, DUTY_CLASS, rope + 1, params,
                     ({"kind": "creep", "mm_per_wind": [round(float(m), 4) for m in mm]},))


def change_fault(f: FaultDraw):
    """The change to the hoist's scenario document (after `change_doc`) that adds the fault."""
    def change(doc: dict) -> None:
        plant = doc["plant"]
        if f.offsets_m is not None:
            plant["ropes"]["offsets_m"] = list(f.offsets_m)
        if f.groove_creep is not None:
            plant["ropes"]["groove_creep"] = list(f.groove_creep)
        if f.faults:
            doc["faults"] = [dict(t) for t in f.faults]
        if f.kind == DUTY_CLASS:
            from ropemon.lab.evaluate import duty_doc
            duty_doc(doc, DUTY_TRIPS, seed=f.seed)
            doc.update(DUTY_STEPS)
    return change


# ---------------------------------------------------------------- scoring


def _alarm_presence(frames, times_s, engine_factory):
    """Per frame and rope: is a deviation alarm (certain or possible) present, and was one
    raised. `engine_factory()` gives a fresh `ropemon.station.alarms.AlarmEngine`."""
    eng = engine_factory()
    n = len(frames)
    ropes = len(frames[0].ropes) if frames else 0
    present = np.zeros((n, ropes), bool)
    raised = np.zeros((n, ropes), bool)
    for k, (f, t) in enumerate(zip(frames, times_s)):
        for ev in eng.update(f, float(t)):
            if ev.kind in DEVIATION_KINDS and ev.action == "raise" and ev.rope is not None:
                raised[k, ev.rope] = True
        for a in eng.active():
            if a.kind in DEVIATION_KINDS and a.present and a.rope is not None:
                present[k, a.rope] = True
    return present, raised


DEVIATION_KINDS = ("deviation", "deviation_possible")


def episodes(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index pairs of the runs of True in a 1-D mask."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.flatnonzero(np.diff(m.astype(int)))
    return list(zip(d[::2].tolist(), d[1::2].tolist()))


def alarm_figures(frames, truth_frames_n: np.ndarray, frame_s: float, engine_factory,
                  valid: np.ndarray | None = None) -> dict:
    """Silent episodes and false warnings of the host's alarms on one wind's frames.

    truth_frames_n: (frames, ropes) true tensions averaged over each frame's window.
    valid: frames that count (e.g. not in a shock window); others neither need nor excuse an alarm.
    """
    times = np.arange(len(frames)) * frame_s
    present, raised = _alarm_presence(frames, times, engine_factory)
    d_true = np.abs((truth_frames_n - truth_frames_n.mean(axis=1, keepdims=True))
                    / truth_frames_n.mean(axis=1, keepdims=True))
    ok = np.ones(len(frames), bool) if valid is None else np.asarray(valid, bool)
    need = int(math.ceil(SILENT_MIN_S / frame_s - 1e-9))
    silent, eps = [], 0
    for r in range(d_true.shape[1]):
        for a, b in episodes((d_true[:, r] > DEVIATION_LIMIT) & ok):
            if b - a < need:
                continue
            eps += 1
            if not present[a:b, r].any():
                silent.append({"rope": r + 1, "t0_s": round(a * frame_s, 1), "t1_s": round(b * frame_s, 1),
                               "true_max_pct": round(float(d_true[a:b, r].max()) * 100, 2)})
    within = (d_true < FALSE_BELOW) & ok[:, None]
    false = int((raised & within).sum())
    return {"episodes": eps, "silent": silent, "false_warnings": false,
            "warning_share": round(float((present & within).sum() / within.sum()), 4) if within.any() else None,
            "true_max_dev_pct": round(float(d_true[ok].max()) * 100, 2) if ok.any() else None}


def superposed_frames(frames, rope: int, step_n: np.ndarray, area_m2: float):
    """The frames with `step_n` (per frame) added to one rope, carried as pressure: the mean,
    min and max tensions and the raw pressure move together, the friction estimate does not."""
    from ropemon.station.protocol import L

    out = []
    for f, dn in zip(frames, step_n):
        ropes = list(f.ropes)
        r = ropes[rope]
        if r.mean_dan != L.TENSION_ABSENT and np.isfinite(dn):
            dd = int(round(dn / 10.0))
            dk = int(round(dn / area_m2 / 1000.0))

            def clamp(v):
                return max(-32767, min(32767, v))
            raw = r.raw_kpa if r.raw_kpa == L.RAW_KPA_ABSENT else max(0, min(0xFFFE, r.raw_kpa + dk))
            ropes[rope] = r._replace(mean_dan=clamp(r.mean_dan + dd), min_dan=clamp(r.min_dan + dd),
                                     max_dan=clamp(r.max_dan + dd), raw_kpa=raw)
        out.append(dataclasses.replace(f, ropes=tuple(ropes)))
    return out


def superposed_alarm_figures(frames, truth_frames_n, frame_s, engine_factory, area_m2, valid=None,
                             level: float = SUPERPOSED) -> dict:
    """`alarm_figures` with a true deviation of +-level superposed on each rope in turn."""
    from ropemon.lab.metrics import deviation_step_n

    out = {"episodes": 0, "silent": [], "false_warnings": 0, "cases": 0}
    for rope in range(truth_frames_n.shape[1]):
        for sign in (1.0, -1.0):
            step = deviation_step_n(truth_frames_n, rope, sign * level)
            t = truth_frames_n.copy()
            t[:, rope] += step
            fig = alarm_figures(superposed_frames(frames, rope, step, area_m2), t, frame_s, engine_factory,
                                valid)
            out["cases"] += 1
            out["episodes"] += fig["episodes"]
            out["false_warnings"] += fig["false_warnings"]
            out["silent"] += [{**s, "superposed": f"{sign * level:+.0%} rope {rope + 1}"} for s in fig["silent"]]
    return out


def quantiles(values) -> dict:
    """Median and 95th percentile of the finite values (None when there are none)."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], float)
    if not v.size:
        return {"median": None, "p95": None, "n": 0}
    return {"median": round(float(np.median(v)), 4), "p95": round(float(np.percentile(v, 95)), 4), "n": int(v.size)}


# ---------------------------------------------------------------- faults: truth and scoring

# The alarm each fault class must raise (`ropemon.station.alarms` kinds) and what it is held to.
FAULT_ALARM_KINDS = {"stroke_offset": ("stroke_limit",), "stroke_creep": ("stroke_limit",),
                     "valve_closed": ("not_equalizing",), "seized_seal": ("not_equalizing",),
                     "leak": ("oil_loss",), DUTY_CLASS: ("rope_adjust",)}
STROKE_DEADLINE_S = 1.0          # stroke limit within 1 s of the piston entering its margin
LOAD_CHANGE_GRACE_S = 1.0        # not equalizing: by the end of the load change that shows it, and this
NOT_EQUALIZING_MIN_TRAVEL_M = 0.2e-3   # a load change shows a rope not equalizing when the others'
NOT_EQUALIZING_SHARE = 0.75            # pistons travel this much (median) and it less than this share of it,
OBSERVABLE_TRAVEL_M = 0.2e-3           # while on the healthy wind it took part and travelled this much more
DEPARTURE_OBSERVABLE_KPA = 100.0       # or its tap's pressure change parts from the others' by this much more
ADVISORY_LEAD_WINDS = 5          # the adjustment advisory at least this many winds before the margin
LOAD_CHANGE_MERGE_S = 0.5


def load_changes(truth, hz: float) -> list[tuple[float, float]]:
    """The wind's load changes from the truth: the payload changing (loading, unloading) or the
    wheel accelerating (`metrics.PhaseRules.accel_m_s2`), as (start, end) s; changes closer
    than LOAD_CHANGE_MERGE_S are one, shorter ones are dropped."""
    from ropemon.lab.metrics import PhaseRules

    payload = np.asarray(truth["payload_kg"], float)
    a = np.asarray(truth["wheel_accel_m_s2"], float)
    on = (np.abs(a) > PhaseRules().accel_m_s2) | np.concatenate([[False], np.diff(payload) != 0])
    spans = [(a0 / hz, b0 / hz) for a0, b0 in episodes(on)]
    merged: list[list[float]] = []
    for t0, t1 in spans:
        if merged and t0 - merged[-1][1] < LOAD_CHANGE_MERGE_S:
            merged[-1][1] = t1
        else:
            merged.append([t0, t1])
    return [(t0, t1) for t0, t1 in merged if t1 - t0 >= LOAD_CHANGE_MERGE_S]


def wind_phases(meta: dict) -> list[tuple[float, float]]:
    """(start, end) s of each wind (the cage moving) of a run, from its phases."""
    return [(float(p["t0_s"]), float(p["t1_s"])) for p in meta.get("phases", []) if p.get("kind") == "wind"]


def _load_change_figures(truth, t: np.ndarray, c0: float, c1: float, r: int):
    """Over one load change of a run: each piston's travel (max - min, m), the others' median, and
    rope r's tap pressure change less the others' median change (kPa; None without tap pressures)."""
    k = (t >= c0) & (t <= c1)
    if not k.any():
        return None
    x = np.asarray(truth["piston_x_m"], float)[k]
    travel = x.max(axis=0) - x.min(axis=0)
    others = float(np.median(np.delete(travel, r)))
    dep = None
    if "p_tap_Pa" in truth:
        p = np.asarray(truth["p_tap_Pa"], float)[k]
        dp = (p[-1] - p[0]) / 1e3
        dep = float(dp[r] - np.median(np.delete(dp, r)))
    return travel, others, dep


def fault_truth(f: FaultDraw, truth, meta: dict, hz: float, stroke_m: float, margin_m: float,
                healthy=None) -> dict:
    """What the faulted run's truth says of its fault: whether it crossed its alarm's threshold
    within the run (`crossed`, `why`), its onset, the physical event the alarm answers (`event_s`)
    and the alarm's deadline. Rope from 0 (None: the node's).

    A closed valve or a seized seal crosses in a load change after its onset where its piston
    travels less than NOT_EQUALIZING_SHARE of the others' (they NOT_EQUALIZING_MIN_TRAVEL_M or more)
    and, against `healthy` (the same hoist's healthy wind's truth: the same trip, so the same load
    changes), that differs observably from how the healthy seal behaved there: on the healthy wind
    the piston took part (NOT_EQUALIZING_SHARE of its others' travel) and travelled
    OBSERVABLE_TRAVEL_M more; or its tap's pressure change parts from the others' by
    DEPARTURE_OBSERVABLE_KPA more than on the healthy wind (a cylinder cut off between tap and
    manifold; its piston may then follow). A healthy seal at rest holds its piston through a load
    change as a seized one does: where the healthy wind's piston held too, the sensors cannot tell.
    Without `healthy` the piston's lag alone decides (every healthy piston taken to move)."""
    t = np.asarray(truth["t_s"], float) if "t_s" in truth else np.arange(len(truth["tension_N"])) / hz
    t_end = float(t[-1])
    x = np.asarray(truth["piston_x_m"], float)
    edge = stroke_m / 2 - margin_m
    r = f.rope - 1
    out = {"rope": r if f.rope > 0 and f.kind != "leak" else None, "onset_s": 0.0, "event_s": None,
           "deadline_s": None, "crossed": False, "why": ""}
    if f.kind in ("stroke_offset", "stroke_creep", DUTY_CLASS):
        inside = np.flatnonzero(np.abs(x[:, r]) >= edge)
        closest = float(edge - np.abs(x[:, r]).max())
        out["closest_gap_mm"] = round(closest * 1e3, 2)
        if not inside.size:
            out["why"] = f"the piston stayed {closest * 1e3:.1f} mm short of its margin"
            return out
        t_in = float(t[inside[0]])
        out.update(event_s=t_in, crossed=True, why=f"the piston entered its margin at {t_in:.1f} s")
        if f.kind == DUTY_CLASS:
            winds = wind_phases(meta)
            out["entry_wind"] = sum(1 for w0, _ in winds if w0 <= t_in)
            out["winds"] = len(winds)
            out["deadline_s"] = None   # held in winds (`ADVISORY_LEAD_WINDS`), not seconds
        else:
            out["deadline_s"] = t_in + STROKE_DEADLINE_S
        return out
    if f.kind == "leak":
        onset = float(f.params["leak_at_s"])
        rate = float(f.params["leak_rate_L_min"])
        if "leaked_m3" in truth:
            leaked = np.asarray(truth["leaked_m3"], float)
            k0 = int(np.searchsorted(t, onset))
            if t_end > onset + 1.0 and k0 < len(t):
                rate = float((leaked[-1] - leaked[k0]) / (t_end - t[k0]) * 60e3)
        out.update(onset_s=onset, event_s=onset, deadline_s=t_end, leak_L_min=round(rate, 4))
        out["crossed"] = rate >= OIL_LOSS_TARGET_L_MIN and onset < t_end
        out["why"] = (f"{rate:.3f} L/min from {onset:.0f} s, "
                      f"{'at or beyond' if out['crossed'] else 'below'} {OIL_LOSS_TARGET_L_MIN} L/min")
        return out
    onset = float(f.params.get("valve_at_s", f.params.get("seize_at_s", 0.0)))
    if f.kind == "valve_closed" and "valve_open" in truth:
        shut = np.flatnonzero(np.asarray(truth["valve_open"], float)[:, r] < 0.5)
        if not shut.size:
            out.update(onset_s=onset, why="the valve never closed in the run")
            return out
        onset = float(t[shut[0]])
    out["onset_s"] = onset
    hz_ = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else hz
    th = None
    if healthy is not None:
        th = np.asarray(healthy["t_s"], float) if "t_s" in healthy else np.arange(len(healthy["piston_x_m"])) / hz
    held_alike = []
    for c0, c1 in load_changes(truth, hz_):
        if c1 <= onset:
            continue
        fig = _load_change_figures(truth, t, max(c0, onset), c1, r)
        if fig is None:
            continue
        travel, others, dep = fig
        lags = others >= NOT_EQUALIZING_MIN_TRAVEL_M and travel[r] < NOT_EQUALIZING_SHARE * others
        where = f"the load change at {c0:.1f}-{c1:.1f} s"
        if th is None:
            if lags:
                out.update(event_s=max(c0, onset), deadline_s=c1 + LOAD_CHANGE_GRACE_S, crossed=True,
                           why=f"{where} (its piston {travel[r] * 1e3:.2f} mm, the others {others * 1e3:.2f} mm)")
                return out
            continue
        hfig = _load_change_figures(healthy, th, max(c0, onset), c1, r)
        if hfig is None:
            continue
        htravel, hothers, hdep = hfig
        took_part = htravel[r] >= NOT_EQUALIZING_SHARE * hothers
        if lags and took_part and htravel[r] - travel[r] >= OBSERVABLE_TRAVEL_M:
            out.update(event_s=max(c0, onset), deadline_s=c1 + LOAD_CHANGE_GRACE_S, crossed=True,
                       why=f"{where} (its piston {travel[r] * 1e3:.2f} mm, the others {others * 1e3:.2f} mm; "
                           f"on the healthy wind {htravel[r] * 1e3:.2f} mm, the others {hothers * 1e3:.2f} mm)")
            return out
        if dep is not None and hdep is not None and abs(dep) - abs(hdep) >= DEPARTURE_OBSERVABLE_KPA:
            out.update(event_s=max(c0, onset), deadline_s=c1 + LOAD_CHANGE_GRACE_S, crossed=True,
                       why=f"{where} (its tap pressure {dep:+.0f} kPa from the others' change, {hdep:+.0f} kPa "
                           f"on the healthy wind; its piston {travel[r] * 1e3:.2f} mm, the others "
                           f"{others * 1e3:.2f} mm)")
            return out
        if lags:
            held_alike.append(f"{c0:.1f}-{c1:.1f} s ({travel[r] * 1e3:.2f} mm against {others * 1e3:.2f} mm; "
                              f"healthy {htravel[r] * 1e3:.2f} mm against {hothers * 1e3:.2f} mm)")
    if held_alike:
        out["why"] = ("its piston held while the others moved only where the healthy seal held it alike (" +
                      "; ".join(held_alike) + "): not observable")
    else:
        out["why"] = "its piston still moved with the others in every load change after the onset"
    return out


def station_settings(physical: dict) -> dict:
    """The alarm settings the station takes from this config (`nodefigures.alarm_settings`, as
    `ropemon monitor` and `ropemon replay --db` do): `station`; and the legacy station before the
    equalizer's alarms, `legacy` (`legacy_deviation_possible=True, equalizer=None`)."""
    from ropemon.station.physical import Physical
    from ropemon.station.nodefigures import NodeFigures, alarm_settings

    s = alarm_settings(NodeFigures.from_physical(Physical.from_dict(physical)))
    names = {fl.name for fl in dataclasses.fields(s)}
    legacy = {"legacy_deviation_possible": True, "equalizer": None, "node_imbalance": True}
    return {"station": s, "legacy": dataclasses.replace(s, **{k: v for k, v in legacy.items() if k in names}),
            "legacy_distinct": set(legacy) <= names}


def station_events(frames, settings) -> list:
    """The alarm events of the station's engine on a run's frames, on the frames' node time, the
    station's loop ticking every `replay.TICK_S` between them (as `ropemon replay --db`)."""
    from ropemon.commission.replay import TICK_S
    from ropemon.station.alarms import AlarmEngine

    eng = AlarmEngine(settings)
    events: list = []
    next_tick = None
    for f in frames:
        t = f.time_ms / 1000.0
        if next_tick is None:
            next_tick = t
        while next_tick <= t:
            events += eng.tick(next_tick)
            next_tick += TICK_S
        events += eng.update(f, t)
    return events


def frame_truth(truth, frames, hz: int, physical: dict):
    """Per frame: node times, true deviations from the mean (frames, ropes), frames that count
    (not in a shock's hold), and the imbalance the seals can hide at the true mean rope tension
    (`uncertainty.hidden_reach`; None where the station has no such function)."""
    from ropemon.lab import evaluate as EV
    from ropemon.lab import metrics as M

    w = hz // int(physical["frame_hz"])
    n = min(len(frames), len(truth["tension_N"]) // w)
    truth_n = np.asarray(truth["tension_N"], float)[: n * w]
    _p, excluded, _s, _pl = EV.scoring_masks(truth, truth_n, hz, float(physical["rated_rope_tension_N"]),
                                             float(physical["hall_marks_m"][-1]))
    t_n = M.window_means(truth_n, w)
    valid = M.window_means(excluded.astype(float), w) == 0.0
    times = np.array([f.time_ms / 1000.0 for f in frames[:n]])
    d = M.deviation_from_mean(t_n)
    hidden = None
    try:
        from ropemon.station.uncertainty import BandParams, hidden_reach
    except ImportError:
        hidden_reach = None
    if hidden_reach is not None and physical.get("friction"):
        band = BandParams.from_physical(physical)
        hidden = np.array([hidden_reach(band, float(m)) for m in t_n.mean(axis=1)])
    return times, d, valid, hidden


def score_alarms(frames, truth, meta, hz: int, physical: dict, settings: dict, fault: FaultDraw | None = None,
                 stroke: tuple[float, float] | None = None, healthy=None) -> dict:
    """The Targets' figures of one run (a healthy wind, or the faulted one with `fault`) for each
    alarm configuration of `settings` (`station_settings`): the healthy-hoist figures, or the fault's
    (`healthy`: the same hoist's healthy wind's truth, for `fault_truth`); the silent ropes either way."""
    from ropemon.lab import metrics as M

    times, d, valid, hidden = frame_truth(truth, frames, hz, physical)
    frames = frames[: len(times)]
    beyond = np.abs(d) > M.DEVIATION_LIMIT
    t_end = float(times[-1]) if len(times) else 0.0
    winds = wind_phases(meta)
    out: dict = {"hidden_known": hidden is not None}
    ft = None
    if fault is not None:
        stroke = stroke or site_stroke()
        ft = fault_truth(fault, truth, meta, hz, *stroke, healthy=healthy)
        out["truth"] = {k: v for k, v in ft.items()}
    for which in ("station", "legacy"):
        ev = station_events(frames, settings[which])
        fig: dict = {"silent": M.silent_ropes(ev, times, d, hidden, valid)}
        if fault is None:
            wind = winds[0] if winds else (0.0, t_end)
            fig["healthy"] = M.healthy_alarm_figures(ev, wind, t_end, times, beyond)
        else:
            fig["fault"] = M.fault_alarm_figures(ev, FAULT_ALARM_KINDS[fault.kind], ft["rope"], ft["onset_s"],
                                                 ft["event_s"] if ft["event_s"] is not None else ft["onset_s"],
                                                 ft["deadline_s"] if ft["deadline_s"] is not None else t_end)
            if fault.kind == DUTY_CLASS:
                fig["fault"]["advisory_wind"] = (sum(1 for w0, _ in winds if w0 <= fig["fault"]["t_alarm_s"])
                                                 if fig["fault"]["t_alarm_s"] is not None else None)
                if ft.get("entry_wind") is not None and fig["fault"]["advisory_wind"] is not None:
                    lead = ft["entry_wind"] - fig["fault"]["advisory_wind"]
                    fig["fault"]["lead_winds"] = lead
                    fig["fault"]["in_time"] = lead >= ADVISORY_LEAD_WINDS
                else:
                    fig["fault"]["lead_winds"] = None
                    fig["fault"]["in_time"] = False
        out[which] = fig
    return out


def run_fault(h: Hoist, f: FaultDraw, wind_dir, physical: dict, settings: dict, seed: int) -> dict:
    """Simulate the hoist with its fault (the same plant and noise seed as its healthy wind), run
    the node as commissioned on it (the healthy wind's config) and score the alarms."""
    import shutil
    import time
    from pathlib import Path

    from ropemon.lab import evaluate as EV
    from ropemon.lab.rundir import NODE_EVALUATED

    t0 = time.monotonic()
    fdir = Path(wind_dir) / ("duty" if f.kind == DUTY_CLASS else "fault")
    out: dict = {"class": f.kind, "rope": f.rope, "params": f.params, "faults": [dict(t) for t in f.faults],
                 "describe": f.describe()}
    try:
        EV.simulate(h.name, fdir / "sim", seed, change_fault(f))
        fdir.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(Path(wind_dir) / NODE_EVALUATED, fdir / NODE_EVALUATED)
        frames = EV.firmware_frames(physical, RunDir(fdir).sensors_path, fdir, fdir / NODE_EVALUATED)
        run = RunDir(fdir)
        out.update(score_alarms(frames, run.truth, run.meta, run.sample_hz, physical, settings, f,
                                healthy=RunDir(wind_dir).truth))
    except (EV.EvaluationError, OSError, ValueError, KeyError) as e:
        out["error"] = f"{type(e).__name__}: {e}"
    out["wall_s"] = round(time.monotonic() - t0, 1)
    return out


# ---------------------------------------------------------------- running


def engine_factories(physical: dict) -> dict:
    """The deviation alarms scored on every wind (population.md): `baseline` is the deviation alarm
    alone (the station before the uncertainty band; `run_wind` feeds it the baseline node's
    frames), `node` the certain alarm and DEVIATION POSSIBLE from the band, as the station raised it
    before it watched the equalizer (`legacy_deviation_possible`; the station as shipped is scored
    by `score_alarms`, faults.md)."""
    from ropemon.station.alarms import AlarmEngine, AlarmSettings
    from ropemon.station.uncertainty import BandParams

    band = BandParams.from_physical(physical)

    def baseline():
        return AlarmEngine(AlarmSettings(stuck_s=None, equalizer=None))

    def node():
        return AlarmEngine(AlarmSettings(stuck_s=None, band=band, legacy_deviation_possible=True, equalizer=None))

    return {"baseline": baseline, "node": node}


def run_wind(seed: int, work, firmware: bool = True, bed: dict | None = None, faults: bool = False,
             duty: bool = False) -> dict:
    """Draw, commission, run and score one hoist's wind (module doc); errors are reported. The
    station's alarms on it are scored for the Targets (`score_alarms`, `targets.healthy`); with
    `faults` the hoist is run again with its drawn fault (`draw_fault`, `targets.fault`), with
    `duty` through a duty cycle with creep (`draw_duty_fault`, `targets.duty`)."""
    import time
    from pathlib import Path

    from ropemon.lab import evaluate as EV
    from ropemon.lab import metrics as M

    h = draw(seed)
    t0 = time.monotonic()
    out: dict = {"seed": seed, "law": h.law, "hoist": h.describe()}
    try:
        case = EV.build_case(h.name, Path(work) / h.name, seed, firmware, bed, diagnostics=False)
        res = EV.score(case)
    except (EV.EvaluationError, OSError, ValueError, KeyError) as e:
        out["error"] = f"{type(e).__name__}: {e}"
        out["wall_s"] = round(time.monotonic() - t0, 1)
        return out
    com = res["commissioning"]
    out["commissioning"] = {"ok": com["ok"] and not com["seal_refused"], "problems": com["problems"],
                            "seal_refused": com["seal_refused"]}
    out["estimators"] = {name: {k: fig.get(k) for k in ("rope_rms_pct", "rope_peak_pct", "pithead_total_pct")}
                         for name, fig in res["estimators"].items()}
    fw = res["estimators"].get(EV.FIRMWARE)
    if fw is not None:
        out["firmware_vs_float_max_pct"] = fw.get("vs_reference_max_pct")
        wind_dir = Path(work) / h.name
        # the same with the reference taking the node's stroke decisions where its own are in doubt
        try:
            out["firmware_vs_float_following"] = follow_figures(RunDir(wind_dir), len(case.truth_n))
        except (OSError, ValueError, KeyError, RuntimeError) as e:
            out["firmware_vs_float_following"] = {"error": f"{type(e).__name__}: {e}"}
        base_case = baseline_case(case, wind_dir)
        fb = EV.score_frames(base_case)
        out["estimators"][BASELINE_FIRMWARE] = {k: fb.get(k) for k in ("rope_rms_pct", "rope_peak_pct",
                                                                        "pithead_total_pct")}
        out["baseline_firmware_vs_float_max_pct"] = fb.get("vs_reference_max_pct")
        w = case.window
        frame_s = w / case.sample_hz
        area = float(np.mean(case.physical["cylinder_area_m2"]))
        out["alarms"] = {}
        for which, factory in engine_factories(case.physical).items():
            c = base_case if which == "baseline" else case
            n = len(c.frames)
            truth = M.window_means(c.truth_n, w)[:n]
            valid = M.window_means(c.excluded.astype(float), w)[:n] == 0.0
            out["alarms"][which] = {
                "natural": alarm_figures(c.frames, truth, frame_s, factory, valid),
                "superposed": superposed_alarm_figures(c.frames, truth, frame_s, factory, area, valid)}
        out["ideal_bound"] = ideal_bound_figures(RunDir(wind_dir).truth, case.physical)
        settings = station_settings(case.physical)
        run = RunDir(wind_dir)
        out["targets"] = {"legacy_distinct": settings["legacy_distinct"],
                          "healthy": score_alarms(case.frames, run.truth, run.meta, case.sample_hz, case.physical,
                                                  settings)}
        if faults:
            out["targets"]["fault"] = run_fault(h, draw_fault(seed, h), wind_dir, case.physical, settings, seed)
        if duty:
            out["targets"]["duty"] = run_fault(h, draw_duty_fault(seed, h), wind_dir, case.physical, settings,
                                               seed)
    out["wall_s"] = round(time.monotonic() - t0, 1)
    return out


BASELINE_FIRMWARE = "firmware-baseline"
BASELINE_NODE = "node-baseline.json"
BASELINE_FRAMES = "frames-baseline.bin"


def baseline_physical(physical: dict) -> dict:
    """The node as it was before it followed proven sliding: the commissioned config with
    slide following off (docs/model.md, "Balancing strokes")."""
    return dict(physical, slide_follow=False)


def baseline_case(case, wind_dir):
    """The case with the baseline node's firmware frames and float reference in place of the node's."""
    from ropemon.lab import estimators as E
    from ropemon.lab import evaluate as EV
    from ropemon.commission import reference
    from ropemon.commission.nodejson import make_node_json, write_node_json

    ph = baseline_physical(case.physical)
    node_json = wind_dir / BASELINE_NODE
    run = RunDir(wind_dir)
    write_node_json(node_json, make_node_json(ph, **run.identity))
    frames = EV.firmware_frames(ph, run.sensors_path, wind_dir, node_json, BASELINE_FRAMES)
    ref = reference.compensate(ph, run.records[: len(case.truth_n)]).tension_n
    return dataclasses.replace(case, frames=frames, firmware_n=EV.frame_means_n(frames),
                               estimates={E.FULL_COMPENSATION: ref}, physical=ph)


def run(seeds, work, jobs: int = 2, firmware: bool = True, bed: dict | None = None, log=None,
        faults: bool = False, duty_seeds=()) -> list[dict]:
    """`run_wind` over the seeds, `jobs` at a time (processes), in seed order; `faults` and
    `duty_seeds` (the seeds also run through a duty cycle with creep) as `run_wind` takes them."""
    from concurrent.futures import ProcessPoolExecutor

    seeds = list(seeds)
    duty_seeds = set(duty_seeds)
    if jobs <= 1:
        results = []
        for s in seeds:
            results.append(run_wind(s, work, firmware, bed, faults, s in duty_seeds))
            if log:
                log(_line(results[-1]))
        return results
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        # the long duty cycles first, so they do not finish last on their own
        order = sorted(seeds, key=lambda s: s not in duty_seeds)
        submitted = {s: pool.submit(run_wind, s, work, firmware, bed, faults, s in duty_seeds) for s in order}
        futures = [submitted[s] for s in seeds]
        results = []
        for f in futures:
            results.append(f.result())
            if log:
                log(_line(results[-1]))
    return results


def _line(r: dict) -> str:
    if "error" in r:
        return f"{PREFIX}{r['seed']}: ERROR {r['error']} ({r['wall_s']} s)"
    fw = r.get("estimators", {}).get("firmware", {})
    al = r.get("alarms", {}).get("node", {})
    silent = len(al.get("natural", {}).get("silent", [])) + len(al.get("superposed", {}).get("silent", []))
    tail = ""
    for key in ("fault", "duty"):
        fa = r.get("targets", {}).get(key)
        if fa is None:
            continue
        if "error" in fa:
            tail += f"; {fa['class']}: ERROR {fa['error']}"
            continue
        st = fa["station"]["fault"]
        tail += (f"; {fa['describe']}: {'crossed' if fa['truth']['crossed'] else 'not crossed'}, "
                 + (f"alarmed {st['latency_s']:+.1f} s" if st["alarmed"] else "not alarmed"))
    return (f"{PREFIX}{r['seed']}: {r['hoist']}: rope RMS {fw.get('rope_rms_pct', float('nan')):.2f} %, "
            f"pithead {fw.get('pithead_total_pct', float('nan')):+.2f} %, silent {silent}, "
            f"false {al.get('natural', {}).get('false_warnings', '-')}{tail} ({r['wall_s']} s)")


def summary(results: list[dict], which: str) -> dict:
    """The figures of one alarm configuration over the winds (`baseline` or `node`), in the
    shape `ropemon evaluate --population --json` prints."""
    from ropemon.lab.evaluate import FIRMWARE

    fw_key = BASELINE_FIRMWARE if which == "baseline" else FIRMWARE
    vs_key = "baseline_firmware_vs_float_max_pct" if which == "baseline" else "firmware_vs_float_max_pct"
    scored = [r for r in results if "error" not in r and FIRMWARE in r.get("estimators", {})]
    # a hoist whose commissioned config the node refuses runs no firmware: reported, not scored
    refused = [r for r in results if "error" not in r and FIRMWARE not in r.get("estimators", {})]
    fw = [r["estimators"][fw_key] for r in scored]
    silent = false = 0
    silent_seeds = []
    for r in scored:
        al = r["alarms"][which]
        if al["natural"]["silent"] or al["superposed"]["silent"]:
            silent += 1
            silent_seeds.append(r["seed"])
        false += al["natural"]["false_warnings"]
    vs = [r.get(vs_key) for r in scored]
    vs = [v for v in vs if v is not None and np.isfinite(v)]
    return {
        "winds": len(scored),
        "errors": sum(1 for r in results if "error" in r),
        "node_refused": [{"seed": r["seed"], "why": "; ".join(r["commissioning"]["problems"])} for r in refused],
        "commissioning_flagged": sum(1 for r in scored if not r["commissioning"]["ok"]),
        "rope_rms_pct": quantiles(f["rope_rms_pct"] for f in fw),
        "rope_peak_pct": quantiles(f["rope_peak_pct"] for f in fw),
        "pithead_total_abs_pct": quantiles(abs(f["pithead_total_pct"]) if f["pithead_total_pct"] is not None
                                           else None for f in fw),
        "silent_winds": silent,
        "silent_seeds": silent_seeds,
        "false_warnings_per_wind": round(false / len(scored), 3) if scored else None,
        "warning_share": quantiles(r["alarms"][which]["natural"].get("warning_share") for r in scored),
        "superposed_false_warnings_per_wind": round(
            sum(r["alarms"][which]["superposed"]["false_warnings"] for r in scored) / max(1, len(scored)), 3),
        "firmware_vs_float_max_pct": round(max(vs), 4) if vs else None,
        "firmware_vs_float_beyond": sum(1 for v in vs if v > VS_FLOAT_PCT),
        **({"following": _following(scored)} if which == "node" else {}),
        # the lab's ideal bound (`ideal_bound_figures`), the same on both: what any fail-safe band could do
        "ideal_bound_warning_share": quantiles(r.get("ideal_bound", {}).get("warning_share") for r in scored),
        "ideal_bound_hoists_warning": sum(1 for r in scored if (r.get("ideal_bound", {}).get("warning_share") or 0) > 0),
        "ideal_bound_missed_frames": sum(r.get("ideal_bound", {}).get("missed_frames", 0)
                                         + r.get("ideal_bound", {}).get("superposed_missed_frames", 0) for r in scored),
    }


VS_FLOAT_PCT = 0.05  # the firmware's target against its float reference, % of rated


def _following(scored: list[dict]) -> dict | None:
    """The node against the reference that follows its stroke decisions in doubt, over the winds."""
    f = [r["firmware_vs_float_following"] for r in scored if "firmware_vs_float_following" in r]
    errors = [x["error"] for x in f if "error" in x]
    f = [x for x in f if "error" not in x]
    if not f:
        return {"errors": errors} if errors else None
    vs = [x["max_pct"] for x in f if np.isfinite(x["max_pct"])]
    return {"max_pct": round(max(vs), 4) if vs else None,
            "beyond": sum(1 for v in vs if v > VS_FLOAT_PCT),
            "followed": sum(x["followed"] for x in f),
            "hoists_followed": sum(1 for x in f if x["followed"]),
            "disputes": sum(x["disputes"] for x in f),
            "hoists_disputed": sum(1 for x in f if x["disputes"]),
            "e_gap_um": round(max(x["e_gap_um"] for x in f), 4),
            "cl_gap_of_vmin": round(max(x["cl_gap_of_vmin"] for x in f), 4),
            "errors": errors}


def by_law(results: list[dict]) -> dict:
    """Estimator x seal family: median and 95th percentile of the worst rope's RMS (% of rated)
    and of |pithead total| (%)."""
    table: dict = {}
    for r in results:
        for est, fig in r.get("estimators", {}).items():
            cell = table.setdefault(est, {}).setdefault(r["law"], {"rms": [], "pithead": []})
            cell["rms"].append(fig.get("rope_rms_pct"))
            p = fig.get("pithead_total_pct")
            cell["pithead"].append(abs(p) if p is not None else None)
    return {est: {law: {"rope_rms_pct": quantiles(c["rms"]), "pithead_total_abs_pct": quantiles(c["pithead"])}
                  for law, c in laws.items()} for est, laws in table.items()}


def _q(cell: dict | None, digits: int = 2) -> str:
    if not cell or cell.get("median") is None:
        return "-"
    return f"{cell['median']:.{digits}f} / {cell['p95']:.{digits}f}"


def markdown(out: dict) -> str:
    """The population's tables: the node against the baseline, estimator x seal family, each wind."""
    pop, base = out["population"], out["baseline"]
    lines = [f"Population: {pop['winds']} winds from the {out['seeds']} seeds"
             f"{' (quick test bed)' if out.get('quick') else ''}, {pop['errors']} errors; "
             f"{len(pop['node_refused'])} more hoists whose commissioned config the node refuses (not scored), "
             f"{pop['commissioning_flagged']} scored with a commissioning problem; {out['wall_s']} s.", ""]
    lines += [f"- refused: seed {r['seed']}: {r['why']}" for r in pop["node_refused"]]
    lines += ["",
             "| figure (median / 95th percentile) | node | baseline |", "|---|---|---|"]
    for key, label in (("rope_rms_pct", "worst rope RMS, % of rated"), ("rope_peak_pct", "worst rope peak, % of rated"),
                       ("pithead_total_abs_pct", "empty-cage pithead total, abs %")):
        lines.append(f"| {label} | {_q(pop[key])} | {_q(base[key])} |")
    lines += [f"| silent winds | {pop['silent_winds']} {pop['silent_seeds'] or ''} | "
              f"{base['silent_winds']} {base['silent_seeds'] or ''} |",
              f"| false warnings per wind (ropes truly within {FALSE_BELOW:.0%}) | {pop['false_warnings_per_wind']} | "
              f"{base['false_warnings_per_wind']} |",
              f"| share of the time a deviation alarm or warning stands on a rope truly within {FALSE_BELOW:.0%} | "
              f"{_q(pop['warning_share'])} | {_q(base['warning_share'])} |",
              f"| false warnings per wind, {SUPERPOSED:.0%} superposed on each rope | "
              f"{pop['superposed_false_warnings_per_wind']} | {base['superposed_false_warnings_per_wind']} |",
              f"| firmware vs float reference, max % of rated (winds beyond {VS_FLOAT_PCT}) | "
              f"{pop['firmware_vs_float_max_pct']} ({pop.get('firmware_vs_float_beyond')}) | "
              f"{base['firmware_vs_float_max_pct']} ({base.get('firmware_vs_float_beyond')}) |", ""]
    fo = pop.get("following")
    if fo and fo.get("errors"):
        lines += [f"- following the node's decisions could not be run on {len(fo['errors'])} winds: "
                  + "; ".join(fo["errors"][:3]), ""]
    if fo and "max_pct" in fo:
        lines += [f"With the float reference following the node's stroke decisions where the two decide apart "
                  f"by rounding (`reference.Follow`: its own rule on the node's values gives the node's decision): "
                  f"firmware vs float reference max {fo['max_pct']} % of rated ({fo['beyond']} winds beyond "
                  f"{VS_FLOAT_PCT}); {fo['followed']} decisions followed on {fo['hoists_followed']} winds; "
                  f"{fo['disputes']} disputed (the node deciding otherwise than its values, or tracking strokes "
                  f"where the reference does not) on "
                  f"{fo['hoists_disputed']} winds. Near the thresholds the two held e at most {fo['e_gap_um']} um "
                  f"apart and the common motion at most {fo['cl_gap_of_vmin']} of the minimum speed.", ""]
    lines += [
              f"An ideal fail-safe bound (`population.ideal_bound_figures`: noise-free displacement, the fitted "
              f"stiffness, {IDEAL_MARGIN:.0%} margin on the seal's force) would warn on "
              f"{pop['ideal_bound_hoists_warning']} of {pop['winds']} hoists, standing for a share "
              f"{_q(pop['ideal_bound_warning_share'])} (median / 95th percentile) of the time on ropes truly within "
              f"{FALSE_BELOW:.0%}, and miss {pop['ideal_bound_missed_frames']} frames beyond the limit.", ""]
    laws = sorted({law for cells in out["by_law"].values() for law in cells})
    lines += ["Worst rope RMS, % of rated (median / 95th percentile), by estimator and seal family:", "",
              "| estimator | " + " | ".join(laws) + " |", "|---|" + "---|" * len(laws)]
    for est, cells in out["by_law"].items():
        lines.append(f"| {est} | " + " | ".join(_q(cells.get(law, {}).get("rope_rms_pct")) for law in laws) + " |")
    lines += ["", "| seed | hoist | firmware RMS % | peak % | pithead % | true max dev % | silent | false |",
              "|---|---|---|---|---|---|---|---|"]
    for r in out["winds"]:
        if "error" in r:
            lines.append(f"| {r['seed']} | {r['hoist']} | ERROR: {r['error']} | | | | | |")
            continue
        fw = r["estimators"].get("firmware", {})
        al = r.get("alarms", {}).get("node", {})
        nat, sup = al.get("natural", {}), al.get("superposed", {})

        def f(x, fmt="{:.2f}"):
            return "-" if x is None else fmt.format(x)
        lines.append(f"| {r['seed']} | {r['hoist']} | {f(fw.get('rope_rms_pct'))} | {f(fw.get('rope_peak_pct'))} | "
                     f"{f(fw.get('pithead_total_pct'), '{:+.2f}')} | {f(nat.get('true_max_dev_pct'))} | "
                     f"{len(nat.get('silent', []))} + {len(sup.get('silent', []))} | {nat.get('false_warnings', '-')} |")
    return "\n".join(lines) + "\n"


def rescore_wind(run_dir, overrides: dict | None = None) -> dict:
    """The alarm figures of a wind already run (`run_wind` with an `--out` directory), from its
    frames and truth, with `overrides` set in the commissioned config's `physical` (e.g. the
    band's keys): for choosing settings on the tuning seeds without re-simulating."""
    from ropemon.lab import evaluate as EV
    from ropemon.lab import metrics as M

    run = RunDir(run_dir)
    physical = run.physical
    physical.update(overrides or {})
    frames = run.frames()   # a decoder per file: the two runs share their sequence numbers
    frames_b = run.frames(BASELINE_FRAMES) if (run.path / BASELINE_FRAMES).exists() else frames
    truth = run.truth
    hz = int(physical["sample_hz"])
    w = hz // int(physical["frame_hz"])
    n = len(frames)
    truth_n = np.asarray(truth["tension_N"], float)[: n * w]
    _phase, excluded, _steady, _payload = EV.scoring_masks(truth, truth_n, hz, float(physical["rated_rope_tension_N"]),
                                                          float(physical["hall_marks_m"][-1]))
    t = M.window_means(truth_n, w)[:n]
    valid = M.window_means(excluded.astype(float), w)[:n] == 0.0
    area = float(np.mean(physical["cylinder_area_m2"]))
    out = {}
    for which, factory in engine_factories(physical).items():
        fr = (frames_b if which == "baseline" else frames)[: len(t)]
        out[which] = {"natural": alarm_figures(fr, t[: len(fr)], w / hz, factory, valid[: len(fr)]),
                      "superposed": superposed_alarm_figures(fr, t[: len(fr)], w / hz, factory, area,
                                                             valid[: len(fr)])}
    out["ideal_bound"] = ideal_bound_figures(truth, physical)
    return out


# ---------------------------------------------------------------- the best a bound could do

IDEAL_MARGIN = 0.10


def ideal_bound_figures(truth, physical: dict, margin: float = IDEAL_MARGIN, frame_samples: int | None = None) -> dict:
    """How often even an ideal fail-safe bound would warn: a lab study on the simulator's truth.

    A fail-safe band must hold for any seal the node may meet, so it can use what is proven:
    the seal's force lies in [-S, S] (S = (1 + margin) Fs(p) + 2 r, as the station's band with
    a tighter margin), and the piston's displacement moves it. Here the displacement is the
    truth's, noise-free. Moving by dx > 0 (the sign convention of `friction_N`: T = p A + F)
    raises the upper bound by at most k dx (k = sigma0, the fitted pre-sliding stiffness) and
    the lower bound by at least k_min dx up to the sliding floor L = (1 - margin) Fc(p) - 2 r,
    with k_min = L / (Fs(p_max) / sigma0) (a full reversal within one pre-sliding distance);
    dx < 0 mirrors it. At rest the bounds stay, cut to [-S, S] as the pressure changes.

    Over frame means, each rope's deviation extremes over the intervals of all ropes
    (`uncertainty.deviation_bounds`' corners) are compared with the 10 % limit. Returns the
    share of frames in which such a bound would warn on ropes truly within `FALSE_BELOW`
    (as the wind is, and with `SUPERPOSED` on each rope in turn), the frames beyond the limit it
    would miss, and how often the true friction stayed inside (`coverage`, per rope: below 1 the
    bound is already too tight to be fail-safe)."""
    from ropemon.lab.metrics import deviation_step_n, window_means
    from ropemon.station.uncertainty import BandParams

    params = dataclasses.replace(BandParams.from_physical(physical), margin=margin)
    fr = physical["friction"]
    x = np.asarray(truth["piston_x_m"], float)
    f_true = np.asarray(truth["friction_N"], float)
    kpa = np.asarray(truth["p_tap_Pa"], float) / 1000.0
    area = np.asarray(physical["cylinder_area_m2"], float)
    n, ropes = x.shape
    s = np.empty_like(x)
    floor_l = np.empty_like(x)
    for k in range(n):   # the band's limits at each rope's pressure
        for i in range(ropes):
            s_ki, fc, flo = params.limits(kpa[k, i])
            s[k, i] = s_ki
            floor_l[k, i] = max(0.0, (1.0 - margin) * fc - flo)
    k_max = float(fr["sigma0"])
    d_pre = float(np.max(s)) / (1.0 + margin) / k_max
    lo, hi = -s[0].copy(), s[0].copy()
    los, his = np.empty_like(x), np.empty_like(x)
    dx_all = np.diff(x, axis=0, prepend=x[:1])
    for k in range(n):
        dx = dx_all[k]
        k_min = floor_l[k] / d_pre
        up, down = dx > 0, dx < 0
        hi = np.where(up, hi + k_max * dx, np.where(down, np.minimum(hi, np.maximum(hi + k_min * dx, -floor_l[k])), hi))
        lo = np.where(down, lo + k_max * dx, np.where(up, np.maximum(lo, np.minimum(lo + k_min * dx, floor_l[k])), lo))
        hi = np.minimum(np.maximum(hi, -floor_l[k]), s[k])
        lo = np.maximum(np.minimum(lo, floor_l[k]), -s[k])
        los[k], his[k] = lo, hi
    coverage = np.mean((f_true >= los - 1.0) & (f_true <= his + 1.0), axis=0)
    w = frame_samples or int(physical["sample_hz"]) // int(physical["frame_hz"])
    m = (n // w) * w
    t = window_means(truth["tension_N"][:m], w)
    pa = window_means(kpa[:m] * 1000.0 * area, w)
    flo = los[:m].reshape(-1, w, ropes).min(axis=1)
    fhi = his[:m].reshape(-1, w, ropes).max(axis=1)

    def shares(t, pa):
        a, b = np.maximum(0.0, pa + flo), pa + fhi
        sa, sb = a.sum(axis=1, keepdims=True), b.sum(axis=1, keepdims=True)
        d_max = ropes * b / (b + sa - a) - 1.0
        d_min = ropes * a / (a + sb - b) - 1.0
        warn = np.maximum(np.abs(d_max), np.abs(d_min)) >= DEVIATION_LIMIT
        d_true = np.abs(t / t.mean(axis=1, keepdims=True) - 1.0)
        within = d_true < FALSE_BELOW
        return float(warn[within].mean()) if within.any() else None, int(((d_true > DEVIATION_LIMIT) & ~warn).sum())

    share, missed = shares(t, pa)
    sup_shares, sup_missed = [], 0
    for rope in range(ropes):
        for sign in (1.0, -1.0):
            step = deviation_step_n(t, rope, sign * SUPERPOSED)
            t2, pa2 = t.copy(), pa.copy()
            t2[:, rope] += step
            pa2[:, rope] += step
            sh, mi = shares(t2, pa2)
            if sh is not None:
                sup_shares.append(sh)
            sup_missed += mi
    return {"warning_share": None if share is None else round(share, 4), "missed_frames": missed,
            "superposed_warning_share": round(float(np.mean(sup_shares)), 4) if sup_shares else None,
            "superposed_missed_frames": sup_missed,
            "coverage_min": round(float(coverage.min()), 4), "margin": margin}


# ---------------------------------------------------------------- the Targets' table

CONFIGS = ("station", "legacy")
CLASS_TARGETS = {"stroke_offset": "stroke limit within 1 s at p95", "stroke_creep": "stroke limit within 1 s at p95",
                 "valve_closed": "within the load change that shows it",
                 "seized_seal": "within the load change that shows it",
                 "leak": f"oil loss >= {OIL_LOSS_TARGET_L_MIN} L/min within the wind",
                 DUTY_CLASS: f"advisory >= {ADVISORY_LEAD_WINDS} winds before the margin"}


def _stats(values) -> dict:
    v = np.asarray([x for x in values if x is not None], float)
    if not v.size:
        return {"median": None, "p95": None, "max": None, "min": None, "n": 0}
    return {"median": round(float(np.median(v)), 2), "p95": round(float(np.percentile(v, 95)), 2),
            "max": round(float(v.max()), 2), "min": round(float(v.min()), 2), "n": int(v.size)}


def _count(into: dict, add: dict) -> None:
    for k, v in add.items():
        into[k] = into.get(k, 0) + v


def targets_summary(results: list[dict]) -> dict:
    """The Targets' figures over the winds (`run_wind`'s `targets`), per alarm configuration."""
    scored = [r for r in results if "targets" in r]
    out: dict = {"hoists": len(scored), "legacy_distinct": all(r["targets"]["legacy_distinct"] for r in scored),
                 "hidden_known": all(r["targets"]["healthy"]["hidden_known"] for r in scored)}
    for which in CONFIGS:
        healthy = [r["targets"]["healthy"][which] for r in scored]
        h = {"winds": len(healthy), "standing_winds": 0, "standing": {}, "raised": 0, "chattering": 0,
             "kinds": {}, "excluded": {}}
        for fig in healthy:
            hh = fig["healthy"]
            h["standing_winds"] += bool(hh["standing"])
            _count(h["standing"], {aid.split(":")[0]: 1 for aid in hh["standing"]})
            h["raised"] += hh["raised"]
            h["chattering"] += len(hh["chattering"])
            _count(h["kinds"], hh["kinds"])
            _count(h["excluded"], hh["excluded"])
        h["raised_per_wind"] = round(h["raised"] / len(healthy), 3) if healthy else None
        silent = {"healthy": {"within_hidden": 0, "beyond_hidden": 0, "unsplit": 0},
                  "faulted": {"within_hidden": 0, "beyond_hidden": 0, "unsplit": 0}}
        for fig in healthy:
            for k in silent["healthy"]:
                silent["healthy"][k] += len(fig["silent"][k])
        classes: dict = {}
        for r in scored:
            for key in ("fault", "duty"):
                fa = r["targets"].get(key)
                if fa is None:
                    continue
                c = classes.setdefault(fa["class"], {"drawn": 0, "errors": 0, "crossed": 0, "alarmed": 0,
                                                     "in_time": 0, "wrong_rope": 0, "missed": 0,
                                                     "not_crossed_alarmed": 0, "latency": [], "lead_winds": [],
                                                     "raised": {}, "any_on_rope": 0})
                c["drawn"] += 1
                if "error" in fa:
                    c["errors"] += 1
                    continue
                for k in silent["faulted"]:
                    silent["faulted"][k] += len(fa[which]["silent"][k])
                f = fa[which]["fault"]
                if not fa["truth"]["crossed"]:
                    c["not_crossed_alarmed"] += bool(f["alarmed"])
                    continue
                c["crossed"] += 1
                _count(c["raised"], f["raised"])
                c["any_on_rope"] += f["any_on_rope"] is not None or (fa["truth"]["rope"] is None and bool(f["raised"]))
                if f["alarmed"]:
                    c["alarmed"] += 1
                    c["in_time"] += bool(f["in_time"])
                    c["latency"].append(f["latency_s"])
                    if f.get("lead_winds") is not None:
                        c["lead_winds"].append(f["lead_winds"])
                elif f["wrong_rope"]:
                    c["wrong_rope"] += 1
                else:
                    c["missed"] += 1
        for c in classes.values():
            c["latency"] = _stats(c["latency"])
            c["lead_winds"] = _stats(c["lead_winds"])
        out[which] = {"healthy": h, "silent": silent, "classes": classes}
    return out


def _cell(x, fmt="{}") -> str:
    return "-" if x is None else fmt.format(x)


def _lat(st: dict) -> str:
    if not st or st.get("median") is None:
        return "-"
    return f"{st['median']:+.1f} / {st['p95']:+.1f} / {st['max']:+.1f}"


def targets_markdown(out: dict, command: str, ran: str | None = None) -> str:
    """docs/evaluation/faults.md: the Targets, fault class by fault class, legacy station beside
    (`ran`: the command that ran the winds, when `command` scored them again)."""
    from ropemon.lab.metrics import STANDING_SHARE

    t = out["targets"]
    st, lg = t["station"], t["legacy"]
    hs, hl = st["healthy"], lg["healthy"]
    n_duty = sum(c["drawn"] for c in (st["classes"].get(DUTY_CLASS, {}),) if c)
    lines = [f"Made by `{command}`" + (f" on the winds `{ran}` ran" if ran else ""), "",
             f"{t['hoists']} scored hoists of the {out['seeds']} seeds, each run healthy and with one drawn fault"
             + (f"; {n_duty} also through a {DUTY_TRIPS}-wind duty cycle with one rope creeping" if n_duty else "")
             + (f"; scored again in {out['wall_s']} s" if ran else f"; {out['wall_s']} s")
             + ". *station*: the alarms as shipped (`nodefigures.alarm_settings` of the "
             "commissioned config); *legacy station*: the same with `legacy_deviation_possible=True, "
             "equalizer=None`, the station before the equalizer's alarms. Both on the same node frames "
             "(`population.station_events`, as `ropemon replay --db`)."
             + ("" if t["legacy_distinct"] else " **These alarm settings have no legacy switch: both columns are "
                                               "the same station.**"), "",
             "A closed valve or a seized seal *crossed* in a load change after its onset where its piston travelled "
             f"under {NOT_EQUALIZING_SHARE:.0%} of the others' ({NOT_EQUALIZING_MIN_TRAVEL_M * 1e3:.1f} mm or more) "
             "while on the same hoist's healthy wind it took part and travelled "
             f"{OBSERVABLE_TRAVEL_M * 1e3:.1f} mm more, or where its tap's pressure change parted from the others' by "
             f"{DEPARTURE_OBSERVABLE_KPA:.0f} kPa more than on the healthy wind: where the healthy seal held its "
             "piston alike, neither positions nor pressures can tell the fault.", ""]
    ex_s = ", ".join(f"{k}: {v}" for k, v in hs["excluded"].items()) or "none"
    ex_l = ", ".join(f"{k}: {v}" for k, v in hl["excluded"].items()) or "none"

    def kinds(d: dict) -> str:
        return ", ".join(f"{k} {v}" for k, v in sorted(d.items(), key=lambda kv: -kv[1])) or "none"
    lines += [f"| healthy hoists ({hs['winds']} winds) | target | station | legacy station |", "|---|---|---|---|",
              f"| winds with an alarm standing through {STANDING_SHARE:.0%} or more of the wind | 0 | "
              f"{hs['standing_winds']} ({kinds(hs['standing'])}) | {hl['standing_winds']} ({kinds(hl['standing'])}) |",
              f"| alarms raised per healthy wind | at most 0.05 | {_cell(hs['raised_per_wind'])} ({kinds(hs['kinds'])}) "
              f"| {_cell(hl['raised_per_wind'])} ({kinds(hl['kinds'])}) |",
              f"| chattering alarms (raised more than twice in a minute) | 0 | {hs['chattering']} | {hl['chattering']} |",
              f"| raises not counted | - | {ex_s} | {ex_l} |", ""]
    lines += ["| fault class | drawn | crossed its threshold | station: alarmed on the right rope (in time) | "
              "wrong rope | missed | station: event to alarm, s, median / p95 / max | target | "
              "legacy station: any alarm on the rope | legacy station raised | not crossed, alarmed anyway |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for cls in (*FAULT_CLASSES, DUTY_CLASS):
        c, cl = st["classes"].get(cls), lg["classes"].get(cls)
        if not c:
            continue
        timing = _lat(c["latency"]) if cls != DUTY_CLASS else (
            f"{c['lead_winds']['median']:g} winds ahead (least {c['lead_winds']['min']:g})"
            if c["lead_winds"]["n"] else "-")
        errors = f" ({c['errors']} errors)" if c["errors"] else ""
        lines.append(f"| {cls.replace('_', ' ')} | {c['drawn']}{errors} "
                     f"| {c['crossed']} | {c['alarmed']} ({c['in_time']}) | {c['wrong_rope']} | {c['missed']} "
                     f"| {timing} | {CLASS_TARGETS[cls]} | {cl['any_on_rope']} of {cl['crossed']} "
                     f"| {kinds(cl['raised'])} | {c['not_crossed_alarmed']} |")
    sh, sf = st["silent"], lg["silent"]
    lines += ["", "Silent ropes: a rope truly beyond 10 % for 2 s or more without an alarm on it (an advisory does "
              "not count), healthy winds + faulted winds:", "",
              "| silent ropes | target | station | legacy station |", "|---|---|---|---|"]
    if t["hidden_known"]:
        lines += [f"| true deviation within the imbalance the commissioning says the seals can hide | reported | "
                  f"{sh['healthy']['within_hidden']} + {sh['faulted']['within_hidden']} | "
                  f"{sf['healthy']['within_hidden']} + {sf['faulted']['within_hidden']} |",
                  f"| beyond it | 0 | {sh['healthy']['beyond_hidden']} + {sh['faulted']['beyond_hidden']} | "
                  f"{sf['healthy']['beyond_hidden']} + {sf['faulted']['beyond_hidden']} |"]
    else:
        lines.append(f"| all (the station gives no hidden imbalance to split them by) | - | "
                     f"{sh['healthy']['unsplit']} + {sh['faulted']['unsplit']} | "
                     f"{sf['healthy']['unsplit']} + {sf['faulted']['unsplit']} |")
    lines += ["", "| seed | fault | crossed (truth) | station | legacy station raised |", "|---|---|---|---|---|"]
    for r in out["winds"]:
        for key in ("fault", "duty"):
            fa = r.get("targets", {}).get(key)
            if fa is None:
                continue
            if "error" in fa:
                lines.append(f"| {r['seed']} | {fa['describe']} | ERROR: {fa['error']} | | |")
                continue
            f, fl = fa["station"]["fault"], fa["legacy"]["fault"]
            tr = fa["truth"]
            res = (f"alarmed {f['latency_s']:+.1f} s (not required)" if f["alarmed"] and not tr["crossed"] else
                   f"{'in time' if f['in_time'] else 'LATE'} {f['latency_s']:+.1f} s" if f["alarmed"] else
                   f"wrong rope {', '.join(str(x + 1) for x in f['wrong_rope'])}" if f["wrong_rope"] else
                   "not alarmed")
            if f.get("lead_winds") is not None:
                res += f", {f['lead_winds']} winds ahead"
            lines.append(f"| {r['seed']} | {fa['describe']} | {'yes' if tr['crossed'] else 'no'}: {tr['why']} "
                         f"| {res} | {kinds(fl['raised'])} |")
    return "\n".join(lines) + "\n"



def rescore_targets(seed: int, work) -> dict:
    """The Targets' figures of a hoist already run (`run_wind` with faults, its directory in `work`)
    re-scored from its stored frames and truth with the station's alarms as they are now, without
    simulating again: the healthy wind, and the faulted wind and duty cycle where they were run."""
    import time
    from pathlib import Path

    t0 = time.monotonic()
    h = draw(seed)
    wind_dir = Path(work) / h.name
    out: dict = {"seed": seed, "law": h.law, "hoist": h.describe()}
    try:
        run = RunDir(wind_dir)
        physical = run.physical
        settings = station_settings(physical)
        out["targets"] = {"legacy_distinct": settings["legacy_distinct"],
                          "healthy": score_alarms(run.frames(), run.truth, run.meta, run.sample_hz, physical,
                                                  settings)}
        for key, sub, drawer in (("fault", "fault", draw_fault), ("duty", "duty", draw_duty_fault)):
            if not (wind_dir / sub / "frames.bin").exists():
                continue
            f = drawer(seed, h)
            fr = RunDir(wind_dir / sub)
            out["targets"][key] = {"class": f.kind, "rope": f.rope, "params": f.params,
                                   "faults": [dict(t) for t in f.faults], "describe": f.describe(),
                                   **score_alarms(fr.frames(), fr.truth, fr.meta, fr.sample_hz, physical, settings, f,
                                                  healthy=run.truth)}
    except (OSError, ValueError, KeyError) as e:
        out["error"] = f"{type(e).__name__}: {e}"
    out["wall_s"] = round(time.monotonic() - t0, 1)
    return out
