"""Scenario files (TOML): load, validate, and build the plant, its inputs and its sensors.

A scenario names a rig (`hoist`: the cage on its ropes in the shaft; `bench`: cylinders
loaded by prescribed forces, the paper's AMESim set-ups), usually a site file for
what the site engineer knows (geometry, pipes to the taps, sensors, rates), and a
[plant] table of hidden truths. docs/simulator.md is the file reference; every
refusal names the field and the reason.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ropemon.station import tomlfields
from ropemon.lab.plant import friction as friction_mod
from ropemon.lab.plant.hydraulics import Local, Path as PipePath, PathSet, Segment
from ropemon.lab.plant.stepper import METHODS
from ropemon.lab.plant.model import (END_STOP_DAMPING_N_S_M, END_STOP_STIFFNESS_N_M, EndStops, Faults, Inputs,
                                     Plant)
from ropemon.lab.plant.motion import Timeline, piecewise_linear
from ropemon.commission.oil import Oil
from ropemon.lab.plant.ropes import HeadRopes, TailRopes
from ropemon.lab.plant.sensors import Fault, SensorSpec
from ropemon.station import files


class ScenarioError(ValueError):
    """A scenario that cannot be run; the message names the field and the reason."""


_MISSING = tomlfields.MISSING
# The longest hoist scenario simulated: 6 h of hoist time (the 50-wind duty cycle of `ropemon evaluate`
# is 1.7 h; its inputs and truth take about 1 GB). A longer one is refused, naming the field,
# rather than running for hours or running out of memory.
MAX_DURATION_S = 6 * 3600.0
# ... and the most grid points (duration / step_s): the 50-wind duty cycle has 1.2 million.
MAX_GRID_POINTS = 5_000_000


def _check_grid(points: int, h: float, duration_s: float) -> None:
    if points > MAX_GRID_POINTS:
        raise ScenarioError(f"step_s: {h:g} s over the {duration_s:g} s simulated is {points} grid points, more "
                            f"than the simulator's limit of {MAX_GRID_POINTS} (a longer step_s or a shorter scenario)")


# The scenario's field readers: tomlfields' (the site description's), raising ScenarioError.
def number(t: dict, key: str, where: str, default: Any = _MISSING, *, gt=None, ge=None, le=None, lt=None) -> float:
    return tomlfields.number(t, key, where, ScenarioError, default, gt=gt, ge=ge, le=le, lt=lt)


def integer(t: dict, key: str, where: str, default: Any = _MISSING, *, lo=None, hi=None) -> int:
    return tomlfields.integer(t, key, where, ScenarioError, default, lo=lo, hi=hi)


def string(t: dict, key: str, where: str, default: Any = _MISSING, *, choices=None) -> str:
    return tomlfields.string(t, key, where, ScenarioError, default, choices=choices)


def table(t: dict, key: str, where: str, default: Any = _MISSING) -> dict:
    return tomlfields.table(t, key, where, ScenarioError, default)


def known(t: dict, where: str, keys: set[str]) -> None:
    tomlfields.known(t, where, keys, ScenarioError)


def per_rope(t: dict, key: str, where: str, n: int, default: Any = _MISSING) -> np.ndarray:
    """A number for every rope, or a list of exactly n numbers."""
    name = f"{where}.{key}"
    if key not in t:
        if default is _MISSING:
            raise ScenarioError(f"{name}: missing")
        return np.full(n, float(default))
    v = t[key]
    if isinstance(v, list):
        if len(v) != n:
            raise ScenarioError(f"{name}: must have one value per rope ({n}), got {len(v)}")
        return np.array([number({key: x}, key, where) for x in v])
    return np.full(n, number(t, key, where))


def schedule(t: dict, key: str, where: str, width: int, default: Any = _MISSING) -> list[tuple[float, ...]]:
    """[[t_s, v1, ...], ...] with ascending times and `width` values per point."""
    name = f"{where}.{key}"
    if key not in t:
        if default is _MISSING:
            raise ScenarioError(f"{name}: missing")
        return default
    v = t[key]
    if not isinstance(v, list) or not v:
        raise ScenarioError(f"{name}: must be a non-empty list of [t_s, value...] points")
    pts = []
    for i, p in enumerate(v):
        if (not isinstance(p, list) or len(p) != width + 1
                or any(isinstance(a, bool) or not isinstance(a, (int, float)) for a in p)):
            raise ScenarioError(f"{name}[{i}]: must be [t_s{', value' * width}] numbers, got {p!r}")
        pts.append(tuple(float(a) for a in p))
    if any(b[0] < a[0] for a, b in zip(pts, pts[1:])):
        raise ScenarioError(f"{name}: times must not decrease")
    return pts


# ---------------------------------------------------------------- what a built scenario is


@dataclass
class Phase:
    kind: str
    label: str
    t0: float
    t1: float


@dataclass
class Scenario:
    name: str
    path: Path
    doc: dict
    rig: str
    plant: Plant
    inputs: Inputs
    step_s: float
    sample_hz: int
    seed: int
    phases: list[Phase]
    sensors: SensorSpec | None
    site: Any
    hidden: dict
    cage_mass_kg: float = 0.0
    tail: TailRopes | None = None
    rated_rope_tension_N: float = 0.0
    steps: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))  # grid indices the solver steps to
    max_step_s: float = 0.0
    bounce_rad_per_step: float = 0.0
    make_inputs: Any = None      # hoist: t -> Inputs for any times
    grid_points: int = 0
    method: str = "bdf2"          # stepper.integrate_fast method: "bdf2" (default) or "ros2"
    faults: list = field(default_factory=list)   # [[faults]] as truth.json lists them (`fault_meta`)

    @property
    def duration_s(self) -> float:
        return (self.grid_points - 1) * self.step_s if self.inputs is None else float(self.inputs.t[-1])

    def plan_steps(self, u: Inputs) -> np.ndarray:
        """Step plan over the grid window u (indices relative to it); a fault's onset (and a valve's
        end of closing) is always a step point."""
        if self.rig != "hoist":
            return np.arange(len(u.t))
        steps = plan_bounce_steps(u, self.step_s, self.bounce_rad_per_step,
                                  max(int(round(self.max_step_s / self.step_s)), 1))
        ev = self.plant.faults.events()
        if ev:
            k0 = int(round(u.t[0] / self.step_s))
            idx = np.array([int(round(e / self.step_s)) - k0 for e in ev])
            idx = idx[(idx > 0) & (idx < len(u.t))]
            if len(idx):
                steps = np.union1d(steps, idx)
        return steps


QUIET_SETTLE_S = 4.0   # after this long with the wheel stopped and the payload constant, steps may be max_step


def plan_bounce_steps(u: Inputs, h0: float, theta: float, m_max: int) -> np.ndarray:
    """Grid indices: each step spans floor(theta / (omega h0)) grid intervals, 1..m_max; at a rest
    whose inputs have not changed for QUIET_SETTLE_S (the bounce has decayed), m_max, never
    stepping over the end of the rest."""
    K = len(u.t)
    omega = np.sqrt(u.k_rope.sum(axis=1) / u.m_inertia)
    m_at = np.clip(np.floor(theta / (omega * h0)), 1, m_max).astype(int)
    still = (u.u_wheel == 0.0) & (u.a_wheel == 0.0) & np.concatenate([[True], np.diff(u.payload_kg) == 0.0])
    # grid points since the last change, and up to the next one
    idx = np.arange(K)
    last_change = np.maximum.accumulate(np.where(still, -1, idx))
    next_change = np.minimum.accumulate(np.where(still, K - 1, idx)[::-1])[::-1]
    settle = int(round(QUIET_SETTLE_S / h0))
    quiet = still & (idx - last_change > settle)
    m_at = np.where(quiet, np.minimum(m_max, np.maximum(next_change - idx - 1, 1)), m_at)
    steps = [0]
    k = 0
    while k < K - 1:
        k = min(k + int(m_at[k]), K - 1)
        steps.append(k)
    return np.array(steps)


def load_scenario(path: Path | str, seed: int | None = None) -> Scenario:
    path = Path(path)
    doc = tomlfields.load(path, ScenarioError, "scenario", files.MAX_SCENARIO_TOML)
    return build(doc, path, seed)


def build(doc: dict, path: Path, seed: int | None = None, eager: bool = True) -> Scenario:
    """The scenario, with its inputs on the whole grid unless eager=False (hoist rigs only: then
    `make_inputs(t)` gives any window and `plan_steps` its steps)."""
    known(doc, "", {"name", "description", "rig", "site", "step_s", "max_step_s", "bounce_rad_per_step", "seed", "method",
                    "plant", "trip", "duty", "bench", "sensors", "faults"})
    rig = string(doc, "rig", "", "hoist", choices=("hoist", "bench"))
    site = None
    if "site" in doc:
        from ropemon.commission.site import SiteError, load_site

        site_file = string(doc, "site", "")
        try:
            site = load_site(path.parent / site_file)
        except SiteError as e:
            raise ScenarioError(f"site ({site_file}): {e}") from None
    elif rig == "hoist":
        raise ScenarioError("site: missing (a hoist scenario needs the site description)")
    seed_v = integer(doc, "seed", "", 1, lo=0) if seed is None else seed
    name = string(doc, "name", "", path.stem)
    if rig == "hoist":
        sc = _build_hoist(doc, path, site, eager)
    else:
        sc = _build_bench(doc, path, site)
    sc.name = str(name)
    sc.seed = seed_v
    # Steps: every grid point on a bench; on a hoist as many grid points per step as keep the
    # rope-cage bounce phase per step below bounce_rad_per_step (omega = sqrt(sum k / M) rises as
    # the hanging ropes shorten), up to max_step_s (docs/simulator.md).
    sc.max_step_s = number(doc, "max_step_s", "", 0.02, gt=0, le=0.05)
    sc.bounce_rad_per_step = number(doc, "bounce_rad_per_step", "", 0.08, gt=0, le=0.5)
    sc.steps = sc.plan_steps(sc.inputs) if sc.inputs is not None else np.zeros(0, dtype=int)
    # Integration method (docs/simulator.md): BDF2; ROS2 only for comparison (it leaves the
    # under-resolved piston/oil/bristle states inconsistent).
    sc.method = string(doc, "method", "", "bdf2", choices=tuple(METHODS))
    sc.sensors = _sensor_spec(table(doc, "sensors", "", {}), site, sc.plant.n, rig)
    return sc


# ---------------------------------------------------------------- shared plant parts


def _oil(pt: dict) -> tuple[Oil, dict]:
    grade = integer(pt, "oil_iso_vg", "plant", 46)
    cst_100C = number(pt, "oil_cst_100C", "plant", gt=0, lt=grade) if "oil_cst_100C" in pt else None
    try:
        oil = Oil.grade(grade, cst_100C, number(pt, "oil_density_15C_kg_m3", "plant", 870.0, gt=700, lt=1100))
    except ValueError as e:
        raise ScenarioError(f"plant.{e}") from None
    return oil, {"oil_iso_vg": grade, "oil_cst_100C": oil.cst_100C, "oil_density_15C_kg_m3": oil.density_15C_kg_m3}


def _locals(v: Any, where: str) -> tuple[Local, ...]:
    if not isinstance(v, list):
        raise ScenarioError(f"{where}: must be a list of {{bore_m, K1, Kinf}} tables")
    out = []
    for i, t in enumerate(v):
        w = f"{where}[{i}]"
        if not isinstance(t, dict):
            raise ScenarioError(f"{w}: must be a table")
        known(t, w, {"bore_m", "K1", "Kinf"})
        out.append(Local(number(t, "bore_m", w, gt=0, le=0.5), number(t, "K1", w, 0.0, ge=0),
                         number(t, "Kinf", w, 0.0, ge=0)))
    return tuple(out)


def _segments(v: Any, where: str) -> tuple[Segment, ...]:
    if isinstance(v, dict):
        v = [v]
    if not isinstance(v, list) or not v:
        raise ScenarioError(f"{where}: must be a table or list of {{length_m, bore_m}} tables")
    out = []
    for i, t in enumerate(v):
        w = f"{where}[{i}]"
        if not isinstance(t, dict):
            raise ScenarioError(f"{w}: must be a table")
        known(t, w, {"length_m", "bore_m"})
        out.append(Segment(number(t, "length_m", w, gt=0), number(t, "bore_m", w, gt=0, le=0.5)))
    return tuple(out)


PLANT_COMMON = {"beta_Pa", "piston_mass_kg", "dead_volume_m3", "junction_volume_m3", "assembly_pipe",
                "assembly_locals", "tap_extra_locals", "oil_iso_vg", "oil_cst_100C", "oil_density_15C_kg_m3",
                "oil_temp_C", "friction", "end_stops"}


def _end_stops(pt: dict, stroke: np.ndarray) -> EndStops:
    """[plant.end_stops]: contact at +-stroke/2 from mid-stroke (x = 0), always present."""
    et = table(pt, "end_stops", "plant", {})
    known(et, "plant.end_stops", {"stiffness_N_m", "damping_N_s_m"})
    return EndStops(tuple(float(a) / 2 for a in stroke),
                    number(et, "stiffness_N_m", "plant.end_stops", END_STOP_STIFFNESS_N_M, ge=1e6, le=1e11),
                    number(et, "damping_N_s_m", "plant.end_stops", END_STOP_DAMPING_N_S_M, ge=0, le=1e8))


FAULT_KINDS = ("valve_closed", "leak", "seized_seal", "creep")
VALVE_SIDES = ("manifold", "cylinder")
MAX_CREEP_MM_PER_WIND = 50.0
MAX_LEAK_L_MIN = 100.0
MAX_SEIZE_FACTOR = 1000.0


@dataclass
class FaultSpec:
    """[[faults]] as read: the plant's `Faults`, the creep per wind (m per rope) and the metadata."""

    faults: Faults
    creep_m_per_wind: np.ndarray
    meta: list


def _faults(doc: dict, n: int, rig: str, duration_s: float, base_scale) -> FaultSpec:
    """[[faults]] tables (docs/simulator.md "Faults"); ropes from 1 in the file, 0-based inside."""
    fl = tomlfields.array(doc, "faults", "", ScenarioError, [], what="[[faults]] tables")
    valve_at, valve_side, seize = [None] * n, [None] * n, [None] * n
    leaks, meta = [], []
    creep = np.zeros(n)
    seen: dict[tuple[str, int], int] = {}
    for i, ft in enumerate(fl):
        w = f"faults[{i}]"
        if not isinstance(ft, dict):
            raise ScenarioError(f"{w}: must be a table")
        kind = string(ft, "kind", w, choices=FAULT_KINDS)

        def onset() -> float:
            at = number(ft, "at_s", w, 0.0, ge=0)
            if at > duration_s:
                raise ScenarioError(f"{w}.at_s: {at:g} s is after the scenario's end ({duration_s:g} s)")
            return at

        def once(rope: int) -> None:
            if (kind, rope) in seen:
                raise ScenarioError(f"{w}.rope: rope {rope + 1} has a {kind} fault already (faults[{seen[kind, rope]}])")
            seen[kind, rope] = i

        if kind == "valve_closed":
            known(ft, w, {"kind", "rope", "at_s", "side"})
            rope = integer(ft, "rope", w, lo=1, hi=n) - 1
            once(rope)
            at, side = onset(), string(ft, "side", w, "manifold", choices=VALVE_SIDES)
            valve_at[rope], valve_side[rope] = at, side
            meta.append({"kind": kind, "rope": rope + 1, "rope_index": rope, "at_s": at, "side": side,
                         "size": None, "size_unit": None})
        elif kind == "leak":
            known(ft, w, {"kind", "rope", "rate_L_min", "at_s"})
            rope = integer(ft, "rope", w, 0, lo=0, hi=n) - 1      # -1: the connecting assembly
            rate = number(ft, "rate_L_min", w, gt=0, le=MAX_LEAK_L_MIN)
            at = onset()
            leaks.append((rope, rate / 60000.0, at))
            meta.append({"kind": kind, "rope": rope + 1, "rope_index": None if rope < 0 else rope, "at_s": at,
                         "where": "manifold" if rope < 0 else "cylinder", "rate_L_min": rate,
                         "size": rate, "size_unit": "L/min"})
        elif kind == "seized_seal":
            known(ft, w, {"kind", "rope", "factor", "at_s"})
            rope = integer(ft, "rope", w, lo=1, hi=n) - 1
            once(rope)
            factor = number(ft, "factor", w, ge=1, le=MAX_SEIZE_FACTOR)
            at = onset()
            seize[rope] = (at, factor)
            meta.append({"kind": kind, "rope": rope + 1, "rope_index": rope, "at_s": at, "factor": factor,
                         "size": factor, "size_unit": "x the seal type's force"})
        else:
            known(ft, w, {"kind", "mm_per_wind"})
            if rig != "hoist":
                raise ScenarioError(f"{w}.kind: creep needs a hoist rig (it acts per wind)")
            once(0)
            mm = per_rope(ft, "mm_per_wind", w, n)
            if np.abs(mm).max() > MAX_CREEP_MM_PER_WIND:
                raise ScenarioError(f"{w}.mm_per_wind: at most {MAX_CREEP_MM_PER_WIND:g} mm per wind on any rope, "
                                    f"got {np.abs(mm).max():g}")
            creep = mm / 1000.0
            for r, v in enumerate(mm):
                if v != 0.0:
                    meta.append({"kind": kind, "rope": r + 1, "rope_index": r, "at_s": 0.0, "mm_per_wind": float(v),
                                 "size": float(v), "size_unit": "mm/wind"})
    return FaultSpec(Faults(n, tuple(valve_at), tuple(valve_side), tuple(leaks), tuple(seize)), creep, meta)


def wind_count(phases: list, timeline, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Winds done by times t (completed wind phases plus the fraction of the current one's distance)
    and its rate (1/s)."""
    winds = [p for p in phases if p.kind == "wind" and p.t1 > p.t0]
    t = np.asarray(t, dtype=float)
    W, Wd = np.zeros(t.shape), np.zeros(t.shape)
    if not winds:
        return W, Wd
    t0 = np.array([p.t0 for p in winds])
    t1 = np.array([p.t1 for p in winds])
    s0 = timeline.evaluate(t0)[0]
    dist = np.abs(timeline.evaluate(t1)[0] - s0)
    s, u, _ = timeline.evaluate(t)
    j = np.searchsorted(t0, t, side="right") - 1       # the last wind started by t (-1: none)
    jj = np.maximum(j, 0)
    inside = (j >= 0) & (t < t1[jj]) & (dist[jj] > 0)
    done = np.where(j >= 0, j + np.where(inside, 0, 1), 0).astype(float)
    frac = np.where(inside, np.abs(s - s0[jj]) / np.where(dist[jj] > 0, dist[jj], 1.0), 0.0)
    return done + frac, np.where(inside, np.abs(u) / np.where(dist[jj] > 0, dist[jj], 1.0), 0.0)


def _paths(pt: dict, n: int, tap_paths: list[PipePath]) -> tuple[PathSet, PathSet, list]:
    """(cavity -> connecting assembly, cavity -> tap) path sets."""
    rest = PipePath(_segments(pt.get("assembly_pipe", {"length_m": 2.0, "bore_m": 0.010}), "plant.assembly_pipe"),
                    _locals(pt.get("assembly_locals", []), "plant.assembly_locals"))
    extra = pt.get("tap_extra_locals", [])
    if not isinstance(extra, list) or (extra and len(extra) != n):
        raise ScenarioError(f"plant.tap_extra_locals: must be a list of one list per rope ({n})")
    taps = [p.then(PipePath((), _locals(extra[i], f"plant.tap_extra_locals[{i}]"))) if extra else p
            for i, p in enumerate(tap_paths)]
    return PathSet([t.then(rest) for t in taps]), PathSet(taps), [t.volume_m3() + rest.volume_m3() for t in taps]


def _friction(pt: dict, n: int):
    return friction_mod.from_table(table(pt, "friction", "plant"), "plant.friction", n_ropes=n)


def _temps(pt: dict, t: np.ndarray) -> np.ndarray:
    v = pt.get("oil_temp_C", 20.0)
    if isinstance(v, list):
        pts = schedule(pt, "oil_temp_C", "plant", 1)
        temp = piecewise_linear(pts, t)
    else:
        temp = np.full(t.shape, number(pt, "oil_temp_C", "plant"))
    if temp.min() < -20 or temp.max() > 80:
        raise ScenarioError("plant.oil_temp_C: must stay within -20..80 C")
    return temp


def _step(doc: dict, default: float, sample_hz: int) -> float:
    h = number(doc, "step_s", "", default, gt=0, le=0.05)
    ratio = h * sample_hz
    if not (abs(ratio - round(ratio)) < 1e-9 or abs(1 / ratio - round(1 / ratio)) < 1e-9):
        raise ScenarioError(f"step_s: must be a multiple or a whole fraction of 1/sample_hz "
                            f"({1 / sample_hz:g} s), got {h:g}")
    return h


# ---------------------------------------------------------------- hoist rig


def _build_hoist(doc: dict, path: Path, site, eager: bool = True) -> Scenario:
    pt = table(doc, "plant", "")
    known(pt, "plant", PLANT_COMMON | {"ropes", "tail_loop_depth_m"})
    n = site.hoist.ropes
    sample_hz = site.rates.sample_hz
    h = _step(doc, 0.5 / sample_hz, sample_hz)
    rt = table(pt, "ropes", "plant")
    known(rt, "plant.ropes", {"EA_N", "kg_per_m", "headframe_m", "damping_ratio", "offsets_m", "groove_creep"})
    head = HeadRopes(EA_N=number(rt, "EA_N", "plant.ropes", gt=0), kg_per_m=number(rt, "kg_per_m", "plant.ropes", gt=0),
                     headframe_m=number(rt, "headframe_m", "plant.ropes", gt=0),
                     damping_ratio=number(rt, "damping_ratio", "plant.ropes", 0.03, ge=0, lt=1),
                     offsets_m=tuple(per_rope(rt, "offsets_m", "plant.ropes", n, 0.0)))
    if max(abs(o) for o in head.offsets_m) > 0.5 * min(c.stroke_m for c in site.cylinders):
        raise ScenarioError("plant.ropes.offsets_m: an offset beyond half the stroke cannot be absorbed")
    # each rope pays out this much more rope per metre the wheel winds (groove diameters differ)
    creep = np.array(per_rope(rt, "groove_creep", "plant.ropes", n, 0.0))
    if np.abs(creep).max() * site.hoist.shaft_depth_m > 0.25 * min(c.stroke_m for c in site.cylinders):
        raise ScenarioError("plant.ropes.groove_creep: over the shaft's depth the ropes would part by more "
                            "than a quarter of the stroke")
    tail = TailRopes(site.hoist.tail_ropes, site.hoist.tail_rope_kg_per_m,
                     number(pt, "tail_loop_depth_m", "plant", site.hoist.shaft_depth_m, gt=0))
    # motion
    timeline, payload_pts, phases, temp_pts = _trip(doc, site)
    T_end = timeline.duration_s
    K = int(round(T_end / h)) + 1
    _check_grid(K, h, T_end)
    oil, oil_hidden = _oil(pt)
    if not temp_pts:
        _temps(pt, np.zeros(1))   # validate the temperature field once
    area = np.array([c.area_m2 for c in site.cylinders])
    stroke = np.array([c.stroke_m for c in site.cylinders])
    dead = per_rope(pt, "dead_volume_m3", "plant", n, 0.3e-3)
    from_site = [PipePath.from_site_pipe(p) for p in site.pipes]
    to_j, to_tap, pipe_vol = _paths(pt, n, from_site)
    fr = _friction(pt, n)
    fs = _faults(doc, n, "hoist", T_end, fr.force_scale)
    plant = Plant(area_m2=area, v0_m3=area * stroke / 2 + dead + np.array(pipe_vol) / 2,
                  piston_mass_kg=per_rope(pt, "piston_mass_kg", "plant", n, 30.0),
                  beta_Pa=number(pt, "beta_Pa", "plant", 1.0e9, gt=1e7, lt=3e9),
                  junction_volume_m3=number(pt, "junction_volume_m3", "plant", 1.0e-3, gt=0),
                  to_junction=to_j, to_tap=to_tap, friction=fr, offsets_m=head.offsets_m, hoist=True,
                  end_stops=_end_stops(pt, stroke), faults=fs.faults)
    m_cage = site.hoist.cage_mass_kg
    creep_w = fs.creep_m_per_wind

    s_w0 = float(timeline.evaluate(np.zeros(1))[0][0])

    def make_inputs(t: np.ndarray) -> Inputs:
        """Inputs at times t (any window of the grid: long duty cycles are built piece by piece)."""
        s_w, u_w, a_w = timeline.evaluate(t)
        payload = piecewise_linear(payload_pts, t)
        temp = piecewise_linear(temp_pts, t) if temp_pts else _temps(pt, t)
        k_rope = head.stiffness(s_w)[:, None] * np.ones(n)
        m_weight = m_cage + payload + tail.hanging_kg(s_w)
        m_inertia = m_weight + n * head.kg_per_m * head.length_m(s_w) / 3
        c_rope = 2 * head.damping_ratio * np.sqrt(k_rope * (m_inertia / n)[:, None])
        zeros = np.zeros((len(t), n))
        # a rope paying out more than the wheel's travel is longer (less tension) as the cage goes down
        y_load = -(s_w - s_w0)[:, None] * creep
        ydot_load = -u_w[:, None] * creep
        if creep_w.any():   # creep per wind: each rope's length grows by mm_per_wind over each wind
            W, Wd = wind_count(phases, timeline, t)
            y_load = y_load - W[:, None] * creep_w
            ydot_load = ydot_load - Wd[:, None] * creep_w
        return Inputs(t=t, k_rope=k_rope, c_rope=c_rope, f_load=zeros, y_load=y_load, ydot_load=ydot_load, a_wheel=a_w,
                      s_wheel=s_w, u_wheel=u_w, m_weight=m_weight, m_inertia=m_inertia, q_pump=np.zeros(len(t)),
                      rho=oil.rho_kg_m3(temp), mu=oil.mu_Pa_s(temp), oil_temp_C=temp, payload_kg=payload)

    u = make_inputs(np.arange(K) * h) if eager else None
    hidden = {"plant": pt, "oil": oil_hidden, "friction_law": fr.name}
    return Scenario(name="", path=path, doc=doc, rig="hoist", plant=plant, inputs=u, step_s=h, sample_hz=sample_hz,
                    seed=0, phases=phases, sensors=None, site=site, hidden=hidden, cage_mass_kg=m_cage, tail=tail,
                    rated_rope_tension_N=site.hoist.rated_rope_tension_N, make_inputs=make_inputs, grid_points=K,
                    faults=fs.meta)


def _trip(doc: dict, site):
    """Timeline, payload schedule, phases and oil temperature schedule from [trip] or [duty]."""
    if ("trip" in doc) == ("duty" in doc):
        raise ScenarioError("trip: give exactly one of [trip] (one sequence of phases) or [duty] (many trips)")
    if "trip" in doc:
        tt = table(doc, "trip", "")
        known(tt, "trip", {"start_depth_m", "start_payload_kg", "v_max_m_s", "a_max_m_s2", "jerk_m_s3", "phase"})
        motion = _motion_limits(tt, "trip")
        depth = number(tt, "start_depth_m", "trip", ge=0, le=site.hoist.shaft_depth_m)
        payload = number(tt, "start_payload_kg", "trip", 0.0, ge=0)
        plist = tt.get("phase")
        if not isinstance(plist, list) or not plist:
            raise ScenarioError("trip.phase: must be a non-empty array of [[trip.phase]] tables")
        return _phases(plist, "trip.phase", depth, payload, motion, site) + ([],)
    dt = table(doc, "duty", "")
    known(dt, "duty", {"trips", "start_depth_m", "v_max_m_s", "a_max_m_s2", "jerk_m_s3", "payload_kg",
                       "oil_temp_C", "rest_s", "load_s", "seed"})
    motion = _motion_limits(dt, "duty")
    trips = integer(dt, "trips", "duty", lo=1, hi=10000)
    rng = np.random.default_rng(integer(dt, "seed", "duty", 7, lo=0))

    def rng_pair(key, default):
        return tomlfields.pair(dt, key, "duty", ScenarioError, default, equal_ok=True)

    pay, temp_r, rest_r, load_r = (rng_pair("payload_kg", [0, 0]), rng_pair("oil_temp_C", [20, 20]),
                                   rng_pair("rest_s", [5, 5]), rng_pair("load_s", [5, 5]))
    if pay[0] < 0:
        raise ScenarioError("duty.payload_kg: must be >= 0")
    for key, (lo, hi) in (("rest_s", rest_r), ("load_s", load_r)):
        if hi > MAX_DURATION_S:
            raise ScenarioError(f"duty.{key}: high must be <= {MAX_DURATION_S:g}, got [{lo:g}, {hi:g}]")
    bottom, top = site.hoist.shaft_depth_m - 2.0, 2.0
    depth = number(dt, "start_depth_m", "duty", bottom, ge=0, le=site.hoist.shaft_depth_m)
    plist: list[dict] = []
    temps: list[float] = []
    for i in range(trips):
        here_bottom = (depth if i == 0 else (bottom if i % 2 == 0 else top)) > site.hoist.shaft_depth_m / 2
        temps.append(float(rng.uniform(*temp_r)))
        if here_bottom:  # load at the bottom, wind up, unload at the top
            plist += [{"kind": "load", "payload_kg": float(rng.uniform(*pay)), "duration_s": float(rng.uniform(*load_r))},
                      {"kind": "rest", "duration_s": float(rng.uniform(*rest_r)), "label": f"trip {i + 1} bottom"},
                      {"kind": "wind", "to_depth_m": top},
                      {"kind": "rest", "duration_s": float(rng.uniform(*rest_r)), "label": f"trip {i + 1} pithead"},
                      {"kind": "load", "payload_kg": 0.0, "duration_s": float(rng.uniform(*load_r))}]
        else:
            plist += [{"kind": "rest", "duration_s": float(rng.uniform(*rest_r)), "label": f"trip {i + 1} pithead"},
                      {"kind": "wind", "to_depth_m": bottom},
                      {"kind": "rest", "duration_s": float(rng.uniform(*rest_r)), "label": f"trip {i + 1} bottom"}]
        plist.append({"kind": "mark"})  # a trip boundary for the temperature schedule
    tl, pay_pts, phases = _phases(plist, "duty", depth, 0.0, motion, site)
    starts = [0.0] + [p.t0 for p in phases if p.kind == "mark"][:-1]
    temp_pts = [(t0, tc) for t0, tc in zip(starts, temps)]
    return tl, pay_pts, [p for p in phases if p.kind != "mark"], temp_pts


def _motion_limits(t: dict, where: str) -> tuple[float, float, float]:
    return (number(t, "v_max_m_s", where, 10.0, gt=0, le=25), number(t, "a_max_m_s2", where, 0.8, gt=0, le=3),
            number(t, "jerk_m_s3", where, 0.5, gt=0, le=10))


def _phases(plist, where, depth, payload, motion, site):
    tl = Timeline(depth)
    pay_pts = [(0.0, payload)]
    phases = []
    t = 0.0
    for i, ph in enumerate(plist):
        w = f"{where}[{i}]"
        if not isinstance(ph, dict):
            raise ScenarioError(f"{w}: must be a table")
        # "mark" (a trip boundary) only in the phases [duty] generates
        kind = string(ph, "kind", w, choices=("rest", "load", "wind") + (("mark",) if where == "duty" else ()))
        label = string(ph, "label", w, "")
        t0 = t
        if kind == "rest":
            known(ph, w, {"kind", "duration_s", "label"})
            d = number(ph, "duration_s", w, gt=0, le=MAX_DURATION_S)
            tl.rest(d)
            t += d
        elif kind == "load":
            known(ph, w, {"kind", "duration_s", "payload_kg", "label"})
            d = number(ph, "duration_s", w, gt=0, le=MAX_DURATION_S)
            new = number(ph, "payload_kg", w, ge=0)
            pay_pts += [(t, payload), (t + d, new)]
            payload = new
            tl.rest(d)
            t += d
        elif kind == "wind":
            known(ph, w, {"kind", "to_depth_m", "label"})
            to = number(ph, "to_depth_m", w, ge=0, le=site.hoist.shaft_depth_m)
            before = tl.duration_s
            tl.move(to - depth, *motion)
            depth = to
            t += tl.duration_s - before
        # else "mark": no time passes
        phases.append(Phase(str(kind), label, t0, t))
        if t > MAX_DURATION_S:  # checked as the phases are laid out: 10000 trips are refused at once
            raise ScenarioError(f"{where}: the phases last more than the simulator's limit of {MAX_DURATION_S:.0f} s "
                                f"(at {w}, {t:.0f} s; fewer or shorter phases)")
    pay_pts.append((t + 1.0, payload))
    return tl, pay_pts, phases


# ---------------------------------------------------------------- bench rig


def _build_bench(doc: dict, path: Path, site) -> Scenario:
    bt = table(doc, "bench", "")
    known(bt, "bench", {"cylinders", "bore_m", "stroke_m", "duration_s", "sample_hz", "loads_N", "load_spring_N_m", "load_damping_N_s_m",
                        "pump_L_min", "tap_pipe", "tap_locals"})
    pt = table(doc, "plant", "")
    known(pt, "plant", PLANT_COMMON)
    n = integer(bt, "cylinders", "bench", lo=1, hi=4)
    if site is not None and site.hoist.ropes != n:
        raise ScenarioError(f"bench.cylinders: must equal the site's ropes ({site.hoist.ropes}) when a site is given")
    sample_hz = site.rates.sample_hz if site is not None else integer(bt, "sample_hz", "bench", 1000, lo=1, hi=100000)
    h = _step(doc, min(1e-3, 1.0 / sample_hz), sample_hz)
    duration = number(bt, "duration_s", "bench", gt=0, le=3600)
    K = int(round(duration / h)) + 1
    _check_grid(K, h, duration)
    t = np.arange(K) * h
    if site is not None:
        area = np.array([c.area_m2 for c in site.cylinders])
        stroke = np.array([c.stroke_m for c in site.cylinders])
        tap_paths = [PipePath.from_site_pipe(p) for p in site.pipes]
    else:
        bore = number(bt, "bore_m", "bench", gt=0, le=1)
        area = np.full(n, math.pi * bore * bore / 4)
        stroke = np.full(n, number(bt, "stroke_m", "bench", gt=0))
        tp = PipePath(_segments(bt.get("tap_pipe", {"length_m": 0.5, "bore_m": 0.012}), "bench.tap_pipe"),
                      _locals(bt.get("tap_locals", []), "bench.tap_locals"))
        tap_paths = [tp] * n
    loads = schedule(bt, "loads_N", "bench", n)
    f_load = np.stack([piecewise_linear([(p[0], p[1 + i]) for p in loads], t) for i in range(n)], axis=1)
    k_load = per_rope(bt, "load_spring_N_m", "bench", n, 0.0)
    c_load = per_rope(bt, "load_damping_N_s_m", "bench", n, 0.0)
    pump = schedule(bt, "pump_L_min", "bench", 1, [(0.0, 0.0)])
    q_pump = piecewise_linear(pump, t) / 60000.0
    oil, oil_hidden = _oil(pt)
    temp = _temps(pt, t)
    rho, mu = oil.rho_kg_m3(temp), oil.mu_Pa_s(temp)
    dead = per_rope(pt, "dead_volume_m3", "plant", n, 0.2e-3)
    to_j, to_tap, pipe_vol = _paths(pt, n, tap_paths)
    fr = _friction(pt, n)
    fs = _faults(doc, n, "bench", duration, fr.force_scale)
    plant = Plant(area_m2=area, v0_m3=area * stroke / 2 + dead + np.array(pipe_vol) / 2,
                  piston_mass_kg=per_rope(pt, "piston_mass_kg", "plant", n, 20.0),
                  beta_Pa=number(pt, "beta_Pa", "plant", 1.0e9, gt=1e7, lt=3e9),
                  junction_volume_m3=number(pt, "junction_volume_m3", "plant", 0.5e-3, gt=0),
                  to_junction=to_j, to_tap=to_tap, friction=fr, offsets_m=np.zeros(n), hoist=False,
                  end_stops=_end_stops(pt, stroke), faults=fs.faults)
    zeros = np.zeros((K, n))
    zk = np.zeros(K)
    u = Inputs(t=t, k_rope=np.tile(k_load, (K, 1)), c_rope=np.tile(c_load, (K, 1)), f_load=f_load, y_load=zeros, ydot_load=zeros,
               a_wheel=zk, s_wheel=zk, u_wheel=zk, m_weight=zk, m_inertia=np.ones(K), q_pump=q_pump, rho=rho, mu=mu,
               oil_temp_C=temp, payload_kg=zk)
    return Scenario(name="", path=path, doc=doc, rig="bench", plant=plant, inputs=u, step_s=h, sample_hz=sample_hz,
                    seed=0, phases=[Phase("bench", "", 0.0, duration)], sensors=None, site=site,
                    hidden={"plant": pt, "oil": oil_hidden, "friction_law": fr.name},
                    rated_rope_tension_N=site.hoist.rated_rope_tension_N if site is not None else float(f_load.max()),
                    faults=fs.meta)


# ---------------------------------------------------------------- sensors


def _sensor_spec(st: dict, site, n: int, rig: str) -> SensorSpec | None:
    known(st, "sensors", {"pressure_noise_Pa", "displacement_noise_m", "adc_noise_counts", "battery_V",
                          "battery_drain_V_per_h", "battery_noise_V", "hall_half_width_m", "hall_spacing_m",
                          "fault", "temperature_noise_C"})
    if site is None:
        return None
    faults = []
    fl = tomlfields.array(st, "fault", "sensors", ScenarioError, [], what="[[sensors.fault]] tables")
    for i, ft in enumerate(fl):
        w = f"sensors.fault[{i}]"
        if not isinstance(ft, dict):
            raise ScenarioError(f"{w}: must be a table")
        known(ft, w, {"kind", "channel", "rope", "start_s", "end_s", "drift_per_s", "spike_size", "spike_rate_hz"})
        kind = string(ft, "kind", w, choices=tuple(Fault.KINDS))
        channel = string(ft, "channel", w, "pressure", choices=tuple(Fault.CHANNELS))
        faults.append(Fault(kind=kind, channel=channel, rope=integer(ft, "rope", w, 0, lo=0, hi=n - 1),
                            start_s=number(ft, "start_s", w, 0.0, ge=0), end_s=number(ft, "end_s", w, 1e18, gt=0),
                            drift_per_s=number(ft, "drift_per_s", w, 0.0),
                            spike_size=number(ft, "spike_size", w, 0.0),
                            spike_rate_hz=number(ft, "spike_rate_hz", w, 1.0, gt=0)))
    return SensorSpec(
        pressure_noise_Pa=number(st, "pressure_noise_Pa", "sensors", 5e3, ge=0),
        displacement_noise_m=number(st, "displacement_noise_m", "sensors", 2e-5, ge=0),
        adc_noise_counts=number(st, "adc_noise_counts", "sensors", 1.0, ge=0),
        battery_V=number(st, "battery_V", "sensors", 3.95, gt=0),
        battery_drain_V_per_h=number(st, "battery_drain_V_per_h", "sensors", 0.02, ge=0),
        battery_noise_V=number(st, "battery_noise_V", "sensors", 0.002, ge=0),
        temperature_noise_C=number(st, "temperature_noise_C", "sensors", 0.1, ge=0),
        hall_half_width_m=number(st, "hall_half_width_m", "sensors", 0.05, gt=0),
        hall_spacing_m=number(st, "hall_spacing_m", "sensors", 0.04, ge=0),
        faults=tuple(faults))
