"""The population's fault draws: seeded, reproducible, within their documented ranges, written as
the plant's scenario tables; and what a faulted run's truth says of its fault (`fault_truth`) on
hand-made truth arrays."""
from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from ropemon.lab import population as P


def within(key: str, value: float) -> bool:
    lo, hi, _kind = P.FAULT_RANGES[key]
    return lo - 1e-9 <= value <= hi + 1e-9


def test_the_fault_draw_is_seeded_and_reproducible():
    assert P.draw_fault(101) == P.draw_fault(101)
    assert P.draw_duty_fault(101) == P.draw_duty_fault(101)
    assert P.draw_fault(101) != P.draw_fault(102)
    # the draw does not change the hoist's own
    assert P.draw(101) == P.draw(101)


def test_every_class_is_drawn_on_the_scoring_seeds_and_each_draw_is_in_its_ranges():
    stroke, margin = P.site_stroke()
    kinds = Counter()
    for seed in P.SCORING_SEEDS:
        h, f = P.draw(seed), P.draw_fault(seed)
        kinds[f.kind] += 1
        assert f.kind in P.FAULT_CLASSES
        p = f.params
        if f.kind == "stroke_offset":
            assert within("stroke_gap_m", p["stroke_gap_m"]) and p["end"] in ("extended", "retracted")
            assert not f.faults and f.groove_creep is None
            # the offsets put the rope's piston the drawn gap short of its margin at its closest
            # predicted approach; every offset within what the plant absorbs (half the stroke)
            hf = P.dataclasses.replace(h, offsets_m=f.offsets_m)
            x0, x1 = P.predicted_x(hf)
            sign = 1 if p["end"] == "extended" else -1
            closest = max(sign * x0[f.rope - 1], sign * x1[f.rope - 1])
            assert closest == pytest.approx(stroke / 2 - margin - p["stroke_gap_m"], abs=2e-5)
            assert max(abs(o) for o in f.offsets_m) < stroke / 2
        elif f.kind == "stroke_creep":
            assert within("creep_start_gap_m", p["creep_start_gap_m"]) and within("creep_end_gap_m", p["creep_end_gap_m"])
            hf = P.dataclasses.replace(h, offsets_m=f.offsets_m, groove_creep=f.groove_creep)
            x0, x1 = P.predicted_x(hf)
            sign = 1 if p["end"] == "extended" else -1
            edge = stroke / 2 - margin
            assert sign * x0[f.rope - 1] == pytest.approx(edge - p["creep_start_gap_m"], abs=2e-5)
            assert sign * x1[f.rope - 1] == pytest.approx(edge - p["creep_end_gap_m"], abs=2e-4)
            # the plant's bound: the ropes part by at most a quarter of the stroke over the shaft
            assert max(abs(c) for c in f.groove_creep) * 810 <= stroke / 4
        elif f.kind == "valve_closed":
            assert f.faults == ({"kind": "valve_closed", "rope": f.rope, "at_s": p["valve_at_s"], "side": p["side"]},)
            assert within("valve_at_s", p["valve_at_s"]) and p["side"] in P.VALVE_SIDES
        elif f.kind == "leak":
            (t,) = f.faults
            assert t["kind"] == "leak" and 0 <= t["rope"] <= P.ROPES
            assert within("leak_rate_L_min", t["rate_L_min"]) and within("leak_at_s", t["at_s"])
        else:
            (t,) = f.faults
            assert t["kind"] == "seized_seal" and 1 <= t["rope"] <= P.ROPES
            assert within("seize_factor", t["factor"]) and within("seize_at_s", t["at_s"])
    assert set(kinds) == set(P.FAULT_CLASSES) and min(kinds.values()) >= 10
    # sized about the thresholds: some leaks at or beyond the target rate, some below it; some
    # stroke draws into the margin, some short of it
    rates = [P.draw_fault(s).params.get("leak_rate_L_min") for s in P.SCORING_SEEDS]
    rates = [r for r in rates if r is not None]
    assert min(rates) < P.OIL_LOSS_TARGET_L_MIN <= max(rates)
    gaps = [P.draw_fault(s).params.get("stroke_gap_m") for s in P.SCORING_SEEDS]
    gaps = [g for g in gaps if g is not None]
    assert min(gaps) < 0 < max(gaps)


def test_the_duty_creep_draw_moves_one_rope_toward_its_margin():
    stroke, margin = P.site_stroke()
    for seed in (101, 102, 150):
        h, f = P.draw(seed), P.draw_duty_fault(seed)
        (t,) = f.faults
        assert t["kind"] == "creep" and len(t["mm_per_wind"]) == P.ROPES
        assert sum(1 for m in t["mm_per_wind"] if m) == 1 and t["mm_per_wind"][f.rope - 1] != 0
        assert within("duty_winds_to_margin", f.params["duty_winds_to_margin"])
        # a rope lengthening by L per wind moves its piston by -3L/4: to the margin in the drawn winds
        x0, _ = P.predicted_x(h)
        sign = 1 if f.params["end"] == "extended" else -1
        per_wind = -0.75 * t["mm_per_wind"][f.rope - 1] / 1e3
        gap = stroke / 2 - margin - sign * x0[f.rope - 1]
        assert sign * per_wind * f.params["duty_winds_to_margin"] == pytest.approx(gap, rel=1e-3)


def test_the_drawn_faults_are_scenarios_the_plant_reads(tmp_path):
    """The hoist's document with its fault is accepted by the plant's scenario reader (each class)."""
    import copy

    from ropemon.lab import evaluate as EV
    from ropemon.lab.plant.scenario import build

    seen = set()
    for seed in P.SCORING_SEEDS:
        f = P.draw_fault(seed)
        if f.kind in seen:
            continue
        seen.add(f.kind)
        doc, path = EV.scenario_doc(P.draw(seed).name, tmp_path / str(seed))
        doc = copy.deepcopy(doc)
        P.change_fault(f)(doc)
        sc = build(doc, path, seed, eager=False)
        assert sc.rig == "hoist"
    assert seen == set(P.FAULT_CLASSES)



def test_the_duty_cycle_is_a_scenario_the_plant_reads_at_its_own_steps(tmp_path):
    """The duty cycle's document (50 winds with one rope creeping) is accepted by the plant at
    DUTY_STEPS, not the field trip's 5 ms: its solver steps are the duty's, its grid within the
    plant's limit, its winds DUTY_TRIPS."""
    import copy

    from ropemon.lab import evaluate as EV
    from ropemon.lab.plant.scenario import build

    seed = P.SCORING_SEEDS[0]
    doc, path = EV.scenario_doc(P.draw(seed).name, tmp_path / "duty")
    doc = copy.deepcopy(doc)
    assert doc.get("step_s", 0.005) > P.DUTY_STEPS["step_s"]
    P.change_fault(P.draw_duty_fault(seed))(doc)
    sc = build(doc, path, seed, eager=False)
    assert sc.step_s == P.DUTY_STEPS["step_s"] and sc.max_step_s == P.DUTY_STEPS["max_step_s"]
    assert sc.bounce_rad_per_step == P.DUTY_STEPS["bounce_rad_per_step"]
    assert doc["duty"]["trips"] == P.DUTY_TRIPS and doc["faults"][0]["kind"] == "creep"
    assert sc.duration_s > P.DUTY_TRIPS * 100.0

def truth_of(n=1300, hz=10.0, ropes=4):
    """A 130 s run at 10 Hz: loading 3-9 s (payload ramps), accelerating 13-27 s, decelerating 95-109 s."""
    t = np.arange(n) / hz
    payload = np.interp(t, [0, 3, 9, 130], [0, 0, 3000, 3000])
    a = np.where((t >= 13) & (t < 27), 0.5, np.where((t >= 95) & (t < 109), -0.5, 0.0))
    x = np.zeros((n, ropes))
    return {"t_s": t, "payload_kg": payload, "wheel_accel_m_s2": a, "piston_x_m": x,
            "tension_N": np.full((n, ropes), 50e3)}


def test_load_changes_from_the_truth():
    tr = truth_of()
    spans = P.load_changes(tr, 10.0)
    assert [(round(a, 1), round(b, 1)) for a, b in spans] == [(3.1, 9.1), (13.0, 27.0), (95.0, 109.0)]


def test_fault_truth_stroke_entry_and_a_piston_that_stays_short():
    tr = truth_of()
    stroke, margin = 0.2, 0.01
    tr["piston_x_m"][:, 1] = np.linspace(0.080, 0.095, 1300)     # enters 0.09 two thirds through
    f = P.FaultDraw(1, "stroke_creep", 2, {"creep_start_gap_m": 0.01, "creep_end_gap_m": -0.005, "end": "extended"})
    ft = P.fault_truth(f, tr, {}, 10.0, stroke, margin)
    k = int(np.flatnonzero(tr["piston_x_m"][:, 1] >= stroke / 2 - margin)[0])
    assert ft["crossed"] and ft["event_s"] == pytest.approx(k / 10.0) and ft["rope"] == 1
    assert ft["deadline_s"] == pytest.approx(ft["event_s"] + P.STROKE_DEADLINE_S)
    tr["piston_x_m"][:, 1] = -0.085                              # 5 mm short of the retracted margin
    ft = P.fault_truth(f, tr, {}, 10.0, stroke, margin)
    assert not ft["crossed"] and ft["closest_gap_mm"] == pytest.approx(5.0)


def test_fault_truth_a_seized_seal_shows_in_the_first_load_change_its_piston_sits_out():
    tr = truth_of()
    t = tr["t_s"]
    moving = np.clip((t - 95) / 14, 0, 1)[:, None] * 1e-3         # every piston 1 mm over the deceleration
    tr["piston_x_m"] = np.repeat(moving, 4, axis=1)
    tr["piston_x_m"][:, 2] *= 0.1                                 # rope 3's only 0.1 mm
    f = P.FaultDraw(1, "seized_seal", 3, {"seize_factor": 20.0, "seize_at_s": 30.0},
                    ({"kind": "seized_seal", "rope": 3, "factor": 20.0, "at_s": 30.0},))
    ft = P.fault_truth(f, tr, {}, 10.0, 0.2, 0.01)
    assert ft["crossed"] and ft["onset_s"] == 30.0 and ft["event_s"] == pytest.approx(95.0)
    assert ft["deadline_s"] == pytest.approx(109.0 + P.LOAD_CHANGE_GRACE_S)
    tr["piston_x_m"][:, 2] = tr["piston_x_m"][:, 0]               # it moves with the others: not shown
    assert not P.fault_truth(f, tr, {}, 10.0, 0.2, 0.01)["crossed"]
    # a valve closed after the last load change shows in none
    tr["piston_x_m"][:, 2] = 0.0
    v = P.FaultDraw(1, "valve_closed", 3, {"valve_at_s": 115.0, "side": "manifold"})
    assert not P.fault_truth(v, tr, {}, 10.0, 0.2, 0.01)["crossed"]


def test_fault_truth_against_the_healthy_wind_a_piston_held_alike_is_not_crossed():
    """With the same hoist's healthy wind: a seized seal's piston that holds where the healthy
    seal held its piston too shows nothing a sensor can tell; where the healthy piston moved
    (0.2 mm more, taking part) it crossed; a cut-off cylinder's tap pressure parting from the
    others' by 100 kPa more than on the healthy wind crosses whatever its piston does."""
    t = truth_of()["t_s"]
    moving = np.clip((t - 95) / 14, 0, 1)[:, None] * 1e-3
    fault, healthy = truth_of(), truth_of()
    fault["piston_x_m"] = np.repeat(moving, 4, axis=1)
    fault["piston_x_m"][:, 2] *= 0.1                               # rope 3's 0.1 mm, the others' 1 mm
    healthy["piston_x_m"] = fault["piston_x_m"].copy()             # the healthy seal held it alike
    f = P.FaultDraw(1, "seized_seal", 3, {"seize_factor": 20.0, "seize_at_s": 30.0},
                    ({"kind": "seized_seal", "rope": 3, "factor": 20.0, "at_s": 30.0},))
    ft = P.fault_truth(f, fault, {}, 10.0, 0.2, 0.01, healthy=healthy)
    assert not ft["crossed"] and "not observable" in ft["why"], ft
    healthy["piston_x_m"][:, 2] = healthy["piston_x_m"][:, 0]      # on the healthy wind it moved 1 mm
    ft = P.fault_truth(f, fault, {}, 10.0, 0.2, 0.01, healthy=healthy)
    assert ft["crossed"] and ft["event_s"] == pytest.approx(95.0) and "healthy wind" in ft["why"]
    healthy["piston_x_m"][:, 2] = 0.8 * healthy["piston_x_m"][:, 0] # moved, but 0.1 mm more only: not told
    fault["piston_x_m"][:, 2] = 0.7 * fault["piston_x_m"][:, 0]
    assert not P.fault_truth(f, fault, {}, 10.0, 0.2, 0.01, healthy=healthy)["crossed"]
    # a manifold-side valve: the tap reads the cut-off cylinder, 300 kPa off the others' change
    healthy["piston_x_m"][:, 2] = fault["piston_x_m"][:, 2]
    p = 4e6 + np.clip((t - 95) / 14, 0, 1)[:, None] * np.array([-1e6, -1e6, -0.7e6, -1e6])
    fault["p_tap_Pa"], healthy["p_tap_Pa"] = p, np.repeat(p[:, :1], 4, axis=1)
    v = P.FaultDraw(1, "valve_closed", 3, {"valve_at_s": 30.0, "side": "manifold"})
    ft = P.fault_truth(v, fault, {}, 10.0, 0.2, 0.01, healthy=healthy)
    assert ft["crossed"] and "tap pressure +29" in ft["why"], ft


def test_fault_truth_leak_rate_from_the_leaked_volume():
    tr = truth_of()
    t = tr["t_s"]
    tr["leaked_m3"] = np.clip(t - 5.0, 0, None) * 0.08e-3 / 60    # 0.08 L/min from 5 s
    f = P.FaultDraw(1, "leak", 0, {"leak_rate_L_min": 0.2, "leak_at_s": 5.0},
                    ({"kind": "leak", "rope": 0, "rate_L_min": 0.2, "at_s": 5.0},))
    ft = P.fault_truth(f, tr, {}, 10.0, 0.2, 0.01)
    assert ft["leak_L_min"] == pytest.approx(0.08, rel=1e-3) and not ft["crossed"] and ft["rope"] is None
    tr["leaked_m3"] = tr["leaked_m3"] * 2
    ft = P.fault_truth(f, tr, {}, 10.0, 0.2, 0.01)
    assert ft["crossed"] and ft["deadline_s"] == pytest.approx(t[-1])
