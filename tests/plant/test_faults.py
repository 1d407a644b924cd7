"""The equalizer's faults in the plant, each against a hand-checked case: the end stops, a closed
valve, an oil leak, a seized seal, rope creep per wind; their Jacobian, the fast kernel, the run's
metadata (docs/simulator.md "Faults")."""
import copy
import json
import tomllib

import numpy as np
import pytest

from ropemon.lab.plant import friction as friction_mod
from ropemon.lab.plant.model import LEAK_KNEE_PA, SEIZE_RAMP_S, TAU_VALVE_S, VALVE_CLOSING_S, leak_flow
from ropemon.lab.plant.output import write_outputs
from ropemon.lab.plant.run import simulate
from ropemon.lab.plant.scenario import build, load_scenario
from ropemon.lab.plant.stepper import Stepper

K_STOP = 2.0e8      # the defaults of [plant.end_stops]
C_STOP = 2.0e5


def _doc(scenarios_dir, name):
    return tomllib.loads((scenarios_dir / f"{name}.toml").read_text())


def _run(doc, scenarios_dir, name="x"):
    return simulate(build(doc, scenarios_dir / f"{name}.toml"))


def _oil(plant, tr, i):
    """Rope i's cavity oil as volume at zero pressure, (V0 - A x) exp(p / beta): the plant's own
    bookkeeping (p' = beta / V (A v - q) conserves it while q = 0)."""
    return (plant.V0[i] - plant.A[i] * tr["piston_x_m"][:, i]) * np.exp(tr["p_cav_Pa"][:, i] / plant.beta)


# ---------------------------------------------------------------- end stops

def _bench_stop_doc(extended: bool) -> dict:
    """Three connected cylinders, bore 100 mm, stroke 0.2 m, on wide short pipes: rope 1's rod
    on a 2e5 N/m load spring, ropes 2 and 3 on constant loads. All start at 20 kN, mid-stroke; then
    rope 1's load rises to 60 kN (slowly, 0.4 kN/s, past 40 kN where its piston meets the stop: a
    piston as slow as a hoist's, not one slammed into its end)
    (its piston drawn out: the extended stop) or ropes 2 and 3's do (rope 1's pushed in: the
    retracted stop). Free, rope 1's piston would go to (60 - 20) kN / 2e5 N/m = 0.2 m; the stop is at
    0.1 m, so it is held there with 60 - 20 - 2e5 x 0.1 = 20 kN (less its penetration d times the spring)
    on the stop: d = 20 kN / (k_stop + 2e5 N/m)."""
    def loads(f):
        return [f, 20000.0, 20000.0] if extended else [20000.0, f, f]
    return {
        "rig": "bench", "step_s": 0.001,
        "bench": {"cylinders": 3, "bore_m": 0.1, "stroke_m": 0.2, "duration_s": 16.0, "sample_hz": 1000,
                  "load_spring_N_m": [2.0e5, 0.0, 0.0], "load_damping_N_s_m": [2.0e3, 0.0, 0.0],
                  "tap_pipe": {"length_m": 0.3, "bore_m": 0.03},
                  "loads_N": [[t] + loads(f) for t, f in ((0.0, 2e4), (0.5, 2e4), (5.5, 3.9e4), (10.5, 4.1e4),
                                                          (12.5, 6e4), (16.0, 6e4))]},
        "plant": {"beta_Pa": 1.0e9, "piston_mass_kg": 20.0, "dead_volume_m3": 0.2e-3, "junction_volume_m3": 0.5e-3,
                  "oil_temp_C": 20.0, "assembly_pipe": {"length_m": 0.5, "bore_m": 0.03},
                  # a seal without a Stribeck drop (Fs = Fc), so the pistons creep at the loads' pace
                  # instead of sticking and slipping
                  "friction": {"law": "lugre", "Fs": {"intercept": 300.0}, "Fc": {"intercept": 300.0},
                               "vs": {"intercept": 0.005}, "sigma2": {"intercept": 2.0e4}, "sigma0": 1.0e8,
                               "sigma1": 1.0e4}},
    }


@pytest.mark.parametrize("extended", [True, False])
def test_end_stop_holds_the_piston_at_the_stroke(tmp_path, extended):
    res = simulate(build(_bench_stop_doc(extended), tmp_path / "stop.toml"))
    tr, t = res.truth, res.t
    x, E = tr["piston_x_m"], tr["end_stop_N"]
    end = t > 14.0
    d_hand = 20000.0 / (K_STOP + 2.0e5)               # 0.1 mm
    sign = 1.0 if extended else -1.0
    # held at the stroke, beyond it by the hand-computed penetration, within what the seals can hold
    # (300 N on rope 1's piston, and on the others' that set the pressure: 600 N, 3 um)
    band = 2 * 300.0 / (K_STOP + 2.0e5)
    assert np.allclose(sign * x[end, 0], 0.1 + d_hand, rtol=0, atol=band)
    assert np.allclose(E[end, 0], -sign * d_hand * K_STOP, rtol=0, atol=band * K_STOP)
    # the other pistons took the oil: half each, but for the oil's compression (the retracted case's
    # 7.6 MPa against 2.5 MPa at the start: 1.1 mm of their 50 mm)
    assert np.allclose(x[end, 1:], -x[end, :1] / 2, rtol=0.05)
    assert np.all(E[end, 1:] == 0.0)
    # the contact force is one-sided: off the stop it is 0; on it, it never pulls
    assert np.all(E[t < 5.0] == 0.0)
    assert np.all(sign * E[:, 0] <= 0.0)
    # the piston's force balance at rest includes the stop: T = p A + F - E
    A = res.scenario.plant.A
    assert np.allclose(tr["tension_N"][end, 0], tr["p_cav_Pa"][end, 0] * A[0] + tr["friction_N"][end, 0]
                       - E[end, 0], rtol=0, atol=5.0)


def test_end_stops_table_sets_the_contact(tmp_path):
    doc = _bench_stop_doc(True)
    doc["plant"]["end_stops"] = {"stiffness_N_m": 5.0e7, "damping_N_s_m": 1.0e5}
    res = simulate(build(doc, tmp_path / "stop.toml"))
    d = 20000.0 / (5.0e7 + 2.0e5)
    assert res.truth["piston_x_m"][-1, 0] == pytest.approx(0.1 + d, abs=2 * 300.0 / 5.0e7)


def test_end_stops_are_at_half_the_site_stroke_from_mid_stroke(scenarios_dir):
    """Plant x = 0 is mid-stroke: the cavity holds half the stroke's oil there (V0 = A s/2 + dead
    + half the pipes), and the stops are at +-s/2 from it."""
    sc = load_scenario(scenarios_dir / "paper-field-trip.toml")
    strokes = np.array([c.stroke_m for c in sc.site.cylinders])
    assert np.allclose(sc.plant.end_stops.half_stroke_m, strokes / 2)
    assert sc.plant.end_stops.stiffness_N_m == K_STOP and sc.plant.end_stops.damping_N_s_m == C_STOP
    assert np.all(sc.plant.V0 > sc.plant.A * strokes / 2)


def test_stroke_limit_scenario_reaches_the_margin_and_the_stop_in_the_wind(scenarios_dir, tmp_path):
    res = simulate(load_scenario(scenarios_dir / "fault-stroke-limit.toml"))
    tr, t = res.truth, res.t
    wind = next(p for p in res.scenario.phases if p.kind == "wind")
    x0 = tr["piston_x_m"][:, 0]
    k_margin = np.argmax(x0 > 0.09)
    assert x0[k_margin] > 0.09 and wind.t0 < t[k_margin] < wind.t1     # into the 10 mm margin mid-wind
    on = np.nonzero(tr["end_stop_N"][:, 0])[0]
    assert len(on) and t[on[0]] < wind.t1
    # held at the stop: the most it goes beyond is its force over the contact stiffness
    assert x0.max() - 0.1 <= -tr["end_stop_N"][:, 0].min() / K_STOP * 1.05 + 1e-6
    assert np.all(tr["end_stop_N"][:, 1:] == 0.0)
    meta = _written_meta(res, tmp_path)
    assert meta["fault_events"]["end_stop_first_contact_s"][0] == pytest.approx(t[on[0]])
    assert meta["fault_events"]["end_stop_first_contact_s"][1:] == [None, None, None]


# ---------------------------------------------------------------- closed valve

@pytest.fixture(scope="module")
def valve_closed(scenarios_dir):
    return simulate(load_scenario(scenarios_dir / "fault-valve-closed.toml"))


def test_closed_valve_keeps_its_cylinders_oil(valve_closed):
    res = valve_closed
    p, tr, t = res.scenario.plant, res.truth, res.t
    i = 1                                      # rope 2's valve, closed from the start
    assert np.all(tr["flow_pipe_m3_s"][:, i] == 0.0)
    assert np.all(tr["valve_open"][:, i] == 0.0) and np.all(tr["valve_open"][:, [0, 2, 3]] == 1.0)
    oil = _oil(p, tr, i)
    # while the others' loads change by 25 kN and more (loading, wind, unloading) ...
    others = tr["tension_N"][:, [0, 2, 3]]
    assert np.ptp(others, axis=0).min() > 25e3
    # ... its oil stays: the cavity volume V0 - A x changes only with the oil's compression
    vol = p.V0[i] - p.A[i] * tr["piston_x_m"][:, i]
    assert np.ptp(vol) > 3e-6                  # compression as its pressure rose 4 MPa: ~0.5 mm of piston
    assert np.abs(oil - oil[0]).max() < 1e-4 * np.ptp(vol)
    # so its rope did not equalize: its tension 15 kN above the others' at the pithead
    k = np.searchsorted(t, 115.0)
    assert tr["tension_N"][k, i] - others[k].mean() > 15e3
    # the tap (between the valve and the cylinder) reads the cut-off cavity
    assert np.array_equal(tr["p_tap_Pa"][:, i], tr["p_cav_Pa"][:, i])
    assert np.ptp(tr["p_cav_Pa"][k] - tr["p_junction_Pa"][k]) > 1e6


def test_valve_closing_mid_wind_on_the_cylinder_side(scenarios_dir):
    """Closed at 40 s between the cylinder and its tap: the trapped oil is kept from then on, and
    the tap reads the connecting assembly's side."""
    doc = _doc(scenarios_dir, "fault-valve-closed")
    doc["faults"] = [{"kind": "valve_closed", "rope": 2, "at_s": 40.0, "side": "cylinder"}]
    res = _run(doc, scenarios_dir)
    p, tr, t = res.scenario.plant, res.truth, res.t
    before = t < 40.0
    after = t >= 40.0 + VALVE_CLOSING_S + 20 * TAU_VALVE_S
    assert np.all(tr["valve_open"][before, 1] == 1.0) and np.all(tr["valve_open"][after, 1] == 0.0)
    assert np.abs(tr["flow_pipe_m3_s"][before, 1]).max() > 1e-8  # it took part before
    oil = _oil(p, tr, 1)[after]
    vol = (p.V0[1] - p.A[1] * tr["piston_x_m"][:, 1])[after]
    assert np.ptp(vol) > 1e-6
    assert np.abs(oil - oil[0]).max() < 1e-4 * np.ptp(vol)
    assert np.array_equal(tr["p_tap_Pa"][after, 1], tr["p_junction_Pa"][after])
    assert np.abs(tr["p_tap_Pa"][after, 1] - tr["p_cav_Pa"][after, 1]).max() > 1e6


# ---------------------------------------------------------------- leak

@pytest.fixture(scope="module")
def leak(scenarios_dir):
    return simulate(load_scenario(scenarios_dir / "fault-leak.toml"))


def test_leaked_volume_is_the_integral_of_its_flow(leak):
    res = leak
    p, tr, t = res.scenario.plant, res.truth, res.t
    rate = 0.3 / 60000.0                        # 0.3 L/min from 15 s, the cavity far above the knee
    assert tr["p_cav_Pa"][:, 2].min() > LEAK_KNEE_PA
    assert np.all(tr["leak_m3_s"][t <= 15.0] == 0.0)
    assert np.allclose(tr["leak_m3_s"][t >= 15.05], rate, rtol=1e-12)   # (samples between step points interpolate)
    assert np.allclose(tr["leaked_m3"], rate * np.maximum(t - 15.0, 0.0), rtol=1e-9, atol=1e-12)
    # the oil left in the device (as volume at zero pressure) falls by what leaked, at the
    # cavity's density, plus the model's own term for flow between pressures (docs/simulator.md)
    ec, ej = np.exp(tr["p_cav_Pa"] / p.beta), np.exp(tr["p_junction_Pa"] / p.beta)
    oil = ((p.V0 - p.A * tr["piston_x_m"]) * ec).sum(axis=1) + p.Vj * ej
    rate_pipes = (tr["flow_pipe_m3_s"] * (ej[:, None] - ec)).sum(axis=1) - tr["leak_m3_s"] * ec[:, 2]
    expected = np.concatenate([[0.0], np.cumsum((rate_pipes[1:] + rate_pipes[:-1]) / 2 * np.diff(t))])
    leaked = tr["leaked_m3"][-1]
    assert leaked == pytest.approx(rate * (t[-1] - 15.0))
    assert np.abs(oil - oil[0] - expected).max() < 1e-3 * leaked
    # so the pistons' sum A x rose by the leaked volume and the oil's compression
    # (its compression: sum V_i (e^(p_i/beta) - 1) + Vj (e^(pj/beta) - 1) grew as the pressures rose)
    sum_ax = (p.A * tr["piston_x_m"]).sum(axis=1)
    comp = ((p.V0 - p.A * tr["piston_x_m"]) * (ec - 1)).sum(axis=1) + p.Vj * (ej - 1)
    assert 0.01 * leaked < comp[-1] - comp[0] < 0.1 * leaked
    assert sum_ax[-1] - sum_ax[0] == pytest.approx(leaked + comp[-1] - comp[0], rel=0.01)


def test_leak_from_the_manifold_and_its_pressure_knee(scenarios_dir):
    doc = _doc(scenarios_dir, "fault-leak")
    doc["faults"] = [{"kind": "leak", "rate_L_min": 0.5, "at_s": 30.0}]    # rope absent: the assembly
    res = _run(doc, scenarios_dir)
    tr, t = res.truth, res.t
    assert tr["leaked_m3"][-1] == pytest.approx(0.5 / 60000.0 * (t[-1] - 30.0), rel=1e-9)
    assert res.scenario.faults[0]["where"] == "manifold" and res.scenario.faults[0]["rope"] == 0
    # below the knee the flow falls linearly to 0: a leak cannot draw a vacuum
    q, dq = leak_flow(np.full(4, 1e-5), np.array([-1e5, 0.0, LEAK_KNEE_PA / 4, 2 * LEAK_KNEE_PA]))
    assert np.allclose(q, [0.0, 0.0, 0.25e-5, 1e-5]) and np.allclose(dq, [0.0, 0.0, 1e-5 / LEAK_KNEE_PA, 0.0])


# ---------------------------------------------------------------- seized seal

def _seize_doc(scenarios_dir, law, seized: bool):
    """The field trip with ropes 1 and 3 wound in and out 12 mm over the wind up (groove_creep): a
    healthy equalizer moves both pistons (light seals, 0.2 x the field trip's: they hold 3 mm of
    rope at the pithead, not 16); rope 1's seal seized at 20 x the type holds its own."""
    doc = _doc(scenarios_dir, "fault-seized-seal")
    doc["plant"]["ropes"]["groove_creep"] = [1.5e-5, 0.0, -1.5e-5, 0.0]
    if law != "lugre":
        doc["plant"]["friction"] = friction_mod.example_table(law)
    doc["plant"]["friction"]["force_scale"] = [0.2] * 4     # seals that let the pistons follow the ropes
    if not seized:
        doc.pop("faults")
    return doc


@pytest.mark.parametrize("law", friction_mod.LAWS)
def test_seized_seal_holds_its_piston_while_the_others_move(scenarios_dir, law):
    res = _run(_seize_doc(scenarios_dir, law, True), scenarios_dir)
    tr = res.truth
    x = tr["piston_x_m"]
    moved = np.ptp(x, axis=0)
    assert moved[2] > 4e-3, moved               # rope 3's piston follows its rope
    # the seized piston: only its presliding and the oil's give (Coulomb-Stribeck, a static law
    # regularised by tanh(v / v_threshold), creeps at v_threshold atanh(F / g): 0.4 mm over the run)
    assert moved[0] < (0.5e-3 if law == "coulomb-stribeck" else 0.1e-3), moved
    assert moved[0] < 0.1 * moved[2]
    assert np.all(tr["seal_scale"][:, 0] == 20.0) and np.all(tr["seal_scale"][:, 1:] == 0.2)
    # its rope carries what its piston does not take up
    assert np.ptp(tr["tension_N"][-1]) > 10e3


def test_a_healthy_seal_moves_in_the_same_case(scenarios_dir):
    res = _run(_seize_doc(scenarios_dir, "lugre", False), scenarios_dir)
    assert np.ptp(res.truth["piston_x_m"][:, 0]) > 8e-3


def test_seal_seizing_mid_run_scales_from_its_onset(scenarios_dir):
    """Mid-run the seal's force rises from its own to the factor over SEIZE_RAMP_S (1 s), in
    proportion to the time since the onset: a sliding seal's force is not multiplied at once."""
    doc = _doc(scenarios_dir, "fault-seized-seal")
    doc["faults"][0].update(at_s=20.0, factor=5.0)
    doc["plant"]["friction"]["force_scale"] = [1.1, 1.0, 0.9, 1.0]
    res = _run(doc, scenarios_dir)
    sc, t = res.truth["seal_scale"], res.t
    assert SEIZE_RAMP_S == 1.0
    assert np.all(sc[t <= 20.0, 0] == 1.1) and np.all(sc[t >= 21.0, 0] == 5.0)   # the type's x 5
    mid = (t > 20.0) & (t < 21.0)
    assert mid.sum() > 10 and np.all(np.diff(sc[mid, 0]) > 0)
    np.testing.assert_allclose(sc[mid, 0], 1.1 + (5.0 - 1.1) * (t[mid] - 20.0), rtol=1e-9)
    assert np.all(sc[:, 2] == 0.9)


# ---------------------------------------------------------------- creep per wind

def test_creep_per_wind_moves_the_offsets_and_the_rest_positions(scenarios_dir):
    """Three winds with low-friction seals (5 % of the field trip's, so the pistons follow within
    2 Fs / k ~ 1 mm at the pithead): after N winds each rope is N x mm_per_wind longer, and its piston's rest
    position moved by the ropes' mean change less its own (sum A x is the trapped oil)."""
    doc = _doc(scenarios_dir, "fault-creep-duty")
    doc["duty"]["trips"] = 3
    # light Coulomb-Stribeck seals (LuGre's deflection, set at a rest's higher pressure, would hold
    # more than its lower Fs after the unloading: refused by the truth check)
    doc["plant"]["friction"] = friction_mod.example_table("coulomb-stribeck")
    doc["plant"]["friction"]["force_scale"] = [0.05] * 4
    res = _run(doc, scenarios_dir)
    tr, t = res.truth, res.t
    mm = np.array(doc["faults"][0]["mm_per_wind"]) * 1e-3
    delta0 = np.array(doc["plant"]["ropes"]["offsets_m"])
    rests = [p for p in res.scenario.phases if p.kind == "rest"]
    first = np.searchsorted(t, rests[0].t1) - 1
    winds_done = 0
    checked = 0
    for ph in res.scenario.phases:
        if ph.kind == "wind":
            winds_done += 1
            continue
        if ph.kind != "rest" or ph.t1 - ph.t0 < 8.0:
            continue
        k = np.searchsorted(t, ph.t1) - 1
        assert np.allclose(tr["rope_offset_m"][k], delta0 + winds_done * mm, rtol=0, atol=1e-12)
        if winds_done:
            d = winds_done * mm
            expect = d.mean() - d           # equal bores
            dx = tr["piston_x_m"][k] - tr["piston_x_m"][first]
            # the seals' band at this rest: 2 Fs over the rope's stiffness
            kr = res.scenario.inputs.k_rope[np.searchsorted(res.scenario.inputs.t, ph.t1) - 1, 0]
            fs = 0.05 * (2500 + 2000 * tr["p_cav_Pa"][k].max() / 1e6)
            assert np.abs(dx - expect).max() < 2 * fs / kr + 0.2e-3, (ph.label, dx, expect)
            checked += 1
    assert winds_done == 3 and checked >= 3
    # the offsets grew over each wind, not as a step
    w = next(p for p in res.scenario.phases if p.kind == "wind")
    mid = np.searchsorted(t, (w.t0 + w.t1) / 2)
    assert 0.3 < (tr["rope_offset_m"][mid, 0] - delta0[0]) / mm[0] < 0.7


# ---------------------------------------------------------------- the equations with faults active

def _faulty_scenario(scenarios_dir, law="lugre"):
    doc = _doc(scenarios_dir, "fault-leak")
    doc["faults"] = [{"kind": "leak", "rope": 3, "rate_L_min": 0.3, "at_s": 0.0},
                     {"kind": "leak", "rate_L_min": 0.2, "at_s": 0.0},
                     {"kind": "valve_closed", "rope": 2, "at_s": 0.05},
                     {"kind": "seized_seal", "rope": 1, "factor": 7.0, "at_s": 0.0}]
    if law != "lugre":
        doc["plant"]["friction"] = friction_mod.example_table(law)
    return build(doc, scenarios_dir / "x.toml")


def _fault_state(p, u, k, rng):
    y = p.rest_state(u)
    y[p.iv] = rng.normal(0, 0.01, p.n)
    y[p.iz] = rng.normal(0, 3e-5, p.n * p.nz)
    y[p.iq] = rng.normal(0, 1e-4, p.n)
    y[p.ip] += rng.normal(0, 1e5, p.n)
    y[p.ix] = [0.1003, -0.1002, 0.05, -0.02]      # ropes 1 and 2 on their stops
    y[p.iv][0], y[p.iv][1] = 0.01, -0.01           # ... pressing in
    y[p.ip][2] = 0.5 * LEAK_KNEE_PA                # rope 3's leak in its knee
    y[p.ipj] = 0.3 * LEAK_KNEE_PA                  # the assembly's too
    y[0] += 1e-3
    y[1] = 0.01
    return y


@pytest.mark.parametrize("law", ["lugre", "maxwell-slip"])
def test_jacobian_with_every_fault_active(scenarios_dir, law):
    sc = _faulty_scenario(scenarios_dir, law)
    p, u = sc.plant, sc.inputs
    k = int(np.searchsorted(u.t, 0.055))          # rope 2's valve half closed
    assert 0.0 < p.faults.closed(u.t[k])[1] < 1.0
    y = _fault_state(p, u, k, np.random.default_rng(3))
    f, J = p.rhs(u, k, y, True)
    assert p.end_stops.force(y[p.ix], y[p.iv])[0][:2].all()
    scale = np.abs(y) * 1e-7 + 1e-12
    for j in range(p.size):
        e = np.zeros(p.size)
        e[j] = scale[j]
        col = (p.rhs(u, k, y + e) - p.rhs(u, k, y - e)) / (2 * scale[j])
        assert np.allclose(J[:, j], col, rtol=1e-4, atol=1e-6 * (np.abs(col).max() + 1e-9)), j
    # the fast kernel: same f, and its block solve equals a dense one
    st = Stepper(p, u)
    fk, jac = st.rhs(k, list(y), True)
    assert np.allclose(fk, f, rtol=1e-12, atol=1e-300)
    c = 0.01
    b = np.random.default_rng(4).normal(size=p.size) * (np.abs(f) + 1)
    dense = np.linalg.solve(np.eye(p.size) - c * J, b)
    fast = np.array(st.solve(st.factor(jac, c), list(b)))
    assert np.allclose(fast, dense, rtol=1e-8, atol=1e-12 * np.abs(dense).max())


def test_healthy_runs_are_unchanged_by_the_fault_machinery(scenarios_dir):
    """No [[faults]], pistons off their stops: the fault terms are exactly zero (the healthy
    field trip's states are those of the equations without them)."""
    sc = load_scenario(scenarios_dir / "short-test.toml")
    p, u = sc.plant, sc.inputs
    assert not p.faults.any
    y = p.rest_state(u)
    f, J = p.rhs(u, 5, y, True)
    plain = copy.copy(p)
    plain.end_stops = None
    f2, J2 = plain.rhs(u, 5, y, True)
    assert np.array_equal(f, f2) and np.array_equal(J, J2)


# ---------------------------------------------------------------- metadata

def _written_meta(res, tmp_path):
    write_outputs(res, tmp_path / "run", {})
    return json.loads((tmp_path / "run" / "truth.json").read_text())


def test_metadata_lists_each_fault_with_its_onset(valve_closed, leak, tmp_path):
    meta = _written_meta(valve_closed, tmp_path / "a")
    assert meta["faults"] == [{"kind": "valve_closed", "rope": 2, "rope_index": 1, "at_s": 0.0, "side": "manifold",
                               "size": None, "size_unit": None}]
    assert meta["end_stops"]["half_stroke_m"] == [0.1] * 4
    for key in ("end_stop_N", "valve_open", "leaked_m3", "leak_m3_s", "seal_scale", "rope_offset_m"):
        assert key in meta["arrays"] and meta["arrays"][key]["unit"]
    meta = _written_meta(leak, tmp_path / "b")
    assert meta["faults"] == [{"kind": "leak", "rope": 3, "rope_index": 2, "at_s": 15.0, "where": "cylinder",
                               "rate_L_min": 0.3, "size": 0.3, "size_unit": "L/min"}]


def test_creep_and_seize_metadata(scenarios_dir):
    sc = load_scenario(scenarios_dir / "fault-creep-duty.toml")
    assert [(f["rope"], f["size"]) for f in sc.faults] == [(1, 2.0), (3, -1.5), (4, 0.5)]
    assert all(f["kind"] == "creep" and f["size_unit"] == "mm/wind" and f["at_s"] == 0.0 for f in sc.faults)
    sc = load_scenario(scenarios_dir / "fault-seized-seal.toml")
    assert sc.faults == [{"kind": "seized_seal", "rope": 1, "rope_index": 0, "at_s": 0.0, "factor": 20.0,
                          "size": 20.0, "size_unit": "x the seal type's force"}]
