"""The plant's equations: Jacobian, fast kernel = numpy model, static equilibrium, oil volume, equalisation."""
import numpy as np
import pytest

from ropemon.lab.plant.stepper import Stepper
from ropemon.lab.plant.model import G
from ropemon.lab.plant.scenario import load_scenario
from ropemon.lab.plant.solver import GAMMA, integrate

NAMES = ["paper-field-trip", "paper-connection-device", "paper-single-cylinder"]


def _random_state(plant, u, rng):
    y = plant.rest_state(u)
    y[plant.iv] = rng.normal(0, 0.01, plant.n)
    y[plant.iz] = rng.normal(0, 3e-5, plant.n)
    y[plant.iq] = rng.normal(0, 1e-4, plant.n)
    y[plant.ip] += rng.normal(0, 1e5, plant.n)
    y[0] += 1e-3
    y[1] = 0.01
    return y


@pytest.mark.parametrize("name", NAMES)
def test_jacobian_matches_finite_differences(scenarios_dir, name):
    sc = load_scenario(scenarios_dir / f"{name}.toml")
    p, u = sc.plant, sc.inputs
    y = _random_state(p, u, np.random.default_rng(1))
    f, J = p.rhs(u, 20, y, True)
    scale = np.abs(y) * 1e-7 + 1e-12
    for j in range(p.size):
        e = np.zeros(p.size)
        e[j] = scale[j]
        col = (p.rhs(u, 20, y + e) - p.rhs(u, 20, y - e)) / (2 * scale[j])
        assert np.allclose(J[:, j], col, rtol=1e-4, atol=1e-6 * (np.abs(col).max() + 1e-9)), j


@pytest.mark.parametrize("name", NAMES)
def test_fast_kernel_is_the_numpy_model(scenarios_dir, name):
    """Same right-hand side, and its block solve of W = I - gamma h J equals a dense solve."""
    sc = load_scenario(scenarios_dir / f"{name}.toml")
    p, u = sc.plant, sc.inputs
    st = Stepper(p, u)
    rng = np.random.default_rng(2)
    for trial in range(4):
        y = _random_state(p, u, rng)
        if trial == 3:   # fast pipe flow: turbulent (Blasius) segments too
            y[p.iq] = rng.choice([-1, 1], p.n) * rng.uniform(2e-3, 4e-3, p.n)
        f, J = p.rhs(u, 10, y, True)
        fk, jac = st.rhs(10, list(y), True)
        assert np.allclose(fk, f, rtol=1e-12, atol=1e-300)
        c = GAMMA * 0.01
        b = rng.normal(size=p.size) * (np.abs(f) + 1)
        dense = np.linalg.solve(np.eye(p.size) - c * J, b)
        fast = np.array(st.solve(st.factor(jac, c), list(b)))
        assert np.allclose(fast, dense, rtol=1e-8, atol=1e-12 * np.abs(dense).max())


def test_fast_and_dense_integrators_agree(scenarios_dir):
    from ropemon.lab.plant.stepper import integrate_fast

    sc = load_scenario(scenarios_dir / "short-test.toml")
    p, u = sc.plant, sc.inputs
    y0 = p.rest_state(u)
    k = len(u.t) // 3
    for method in ("bdf2", "ros2"):
        dense = integrate(p, u.take(np.arange(k)), sc.step_s, y0, method=method)
        fast = integrate_fast(p, u, y0, list(range(k)), method=method)
        assert np.allclose(fast, dense, rtol=1e-7, atol=1e-9 * np.abs(dense).max(axis=0)), method


@pytest.mark.parametrize("name", NAMES)
def test_static_equilibrium(scenarios_dir, name):
    """At the initial rest: no motion, no flow, every rate zero, and T = p_cav A + F exactly."""
    sc = load_scenario(scenarios_dir / f"{name}.toml")
    p, u = sc.plant, sc.inputs
    u.q_pump[:] = 0.0   # the single-cylinder bench starts its pump at t = 0: look at the rest before
    y = p.rest_state(u)
    f = p.rhs(u, 0, y)
    assert np.abs(f).max() < 1e-9
    out = p.outputs(u.take(np.array([0])), y[None, :])
    T, pc, F = out["tension_N"][0], out["p_cav_Pa"][0], out["friction_N"][0]
    assert np.array_equal(T, pc * p.A + F) or np.allclose(T, pc * p.A + F, rtol=1e-15)
    if sc.rig == "hoist":
        assert T.sum() == pytest.approx(u.m_weight[0] * G, rel=1e-12)


def test_tension_equals_pressure_force_plus_friction_at_every_rest(field_trip):
    """Massless-piston balance T = p_cav A + F once the piston's inertia has nothing to do."""
    tr, A = field_trip.truth, field_trip.scenario.plant.A
    for ph in field_trip.scenario.phases:
        if ph.kind == "rest":
            k = np.searchsorted(field_trip.t, ph.t1) - 1
            assert np.allclose(tr["tension_N"][k], tr["p_cav_Pa"][k] * A + tr["friction_N"][k], rtol=0, atol=2.0)


def test_oil_volume_is_conserved_across_the_connected_cylinders(connection_device):
    """Oil volume at zero pressure, M = sum V_i exp(p_i / beta) + Vj exp(pj / beta), changes only by the
    model's own term dM/dt = sum q_i (exp(pj / beta) - exp(p_i / beta)) (flow measured at the pipe's
    pressure); what is left is solver error, tiny against the oil the pistons move."""
    res = connection_device
    p, tr, t = res.scenario.plant, res.truth, res.t
    vol = p.V0 - p.A * tr["piston_x_m"]
    ec, ej = np.exp(tr["p_cav_Pa"] / p.beta), np.exp(tr["p_junction_Pa"] / p.beta)
    oil = (vol * ec).sum(axis=1) + p.Vj * ej
    rate = (tr["flow_pipe_m3_s"] * (ej[:, None] - ec)).sum(axis=1)
    expected = np.concatenate([[0.0], np.cumsum((rate[1:] + rate[:-1]) / 2 * np.diff(t))])
    swept = np.abs(p.A * (tr["piston_x_m"] - tr["piston_x_m"][0])).sum(axis=1).max()
    assert swept > 5e-5   # the step really moves oil between cylinders
    assert np.abs(oil - oil[0] - expected).max() < 2e-5 * swept
    # the pistons' net displacement is only the oil's compression as the pressure rose
    dx = p.A * (tr["piston_x_m"][-1] - tr["piston_x_m"][0])
    assert 0 < dx.sum() < 0.05 * np.abs(dx).sum()


def test_equalisation_after_a_load_imbalance(connection_device):
    res = connection_device
    pc = res.truth["p_cav_Pa"]
    t = res.t
    spread = pc.max(axis=1) - pc.min(axis=1)
    after = t > 3.0
    assert spread[after].max() > 0.3e6            # the step unbalances the cavities...
    end = t > t[-1] - 0.2
    assert spread[end].max() < 0.005 * pc[end].mean()   # ...and the device brings them back together
    # rope loads equalise to within the seals' static friction band, T_i = p A + F_i, |F_i| <= Fs(p)
    T = res.truth["tension_N"][-1]
    fr = res.scenario.plant.friction
    fs = fr.Fs.at(pc[-1].max() / 1e6)
    assert np.abs(T - pc[-1] * res.scenario.plant.A).max() <= 1.05 * fs
    assert np.ptp(res.truth["load_input_N"][-1]) > 10 * fs   # against loads that differ far more


def test_chunked_inputs_give_the_same_run(scenarios_dir):
    """Long runs turn inputs into Python lists a chunk of steps at a time: same states, bit for bit."""
    from ropemon.lab.plant.stepper import integrate_fast

    sc = load_scenario(scenarios_dir / "short-test.toml")
    p, u = sc.plant, sc.inputs
    steps = sc.steps.tolist()[:600]
    a = integrate_fast(p, u, p.rest_state(u), steps)
    b = integrate_fast(p, u, p.rest_state(u), steps, chunk=7)
    last = integrate_fast(p, u, p.rest_state(u), steps, chunk=50, keep=False)
    assert np.array_equal(a, b)
    assert last.shape == (1, p.size) and np.array_equal(last[0], a[-1])
