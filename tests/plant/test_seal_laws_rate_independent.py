"""The two rate-independent seal laws beside the four (rate_independent.py): Dahl and second-order
Bliman-Sorine, against hand-calculated cases (law alone, quasi-static, at 4 MPa: Fs = 10500 N,
Fc = 6500 N of the example lines), then inside the plant (Jacobian, a short-test run by the dense
BDF2, its step halved), their tables, and the population's held-out draws."""
import math
import tomllib

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ropemon.lab import population as P
from ropemon.lab import testbed
from ropemon.lab.plant.convergence import halved_doc, x_minus_integral_of_v
from ropemon.lab.plant.friction import ALL_LAWS, LAWS, MORE_LAWS, example_table, from_table
from ropemon.lab.plant.rate_independent import BlimanSorine, Dahl
from ropemon.lab.plant.run import check_truth
from ropemon.lab.plant.scenario import ScenarioError, build
from ropemon.lab.plant.solver import integrate, state_scale
from ropemon.lab.plant.stepper import Stepper, integrate_fast

P_PA = 4e6
FC, FS = 1700.0 + 1200.0 * 4, 2500.0 + 2000.0 * 4     # 6500 N, 10500 N at 4 MPa
NO_RATE = {"sigma2": {"intercept": 0.0, "slope": 0.0}}


def _law(name, **changes):
    t = example_table(name)
    t.update(changes)
    return from_table(t, "plant.friction")


def _branch(law, z0, v, x_len, n_pts=2001):
    """States and force along a displacement x_len at constant v and P_PA from z0: the law's own
    rate integrated in displacement (dz/dx = zdot / v), tightly."""
    p, M = np.array([P_PA]), law.n_z
    shape = (lambda z: z) if M == 1 else (lambda z: z[None, :])

    def f(_x, z):
        return np.ravel(law.evaluate(np.array([v]), shape(z), p).zdot) / v

    def jac(_x, z):
        return np.diag(np.ravel(law.evaluate(np.array([v]), shape(z), p).zd_z) / v)

    xs = np.linspace(0.0, x_len, n_pts)
    sol = solve_ivp(f, (0.0, x_len), np.atleast_1d(np.asarray(z0, dtype=float)), method="Radau", t_eval=xs,
                    jac=jac, rtol=1e-10, atol=1e-15)
    assert sol.success
    Z = sol.y.T if M > 1 else sol.y[0]
    return xs, law.evaluate(np.full(len(xs), v), Z, np.full(len(xs), P_PA)).F


# ---------------------------------------------------------------- Dahl, hand-checked


@pytest.mark.parametrize("exponent", [1.0, 2.0])
def test_dahl_virgin_curve_is_dahls_closed_form(exponent):
    """From an unloaded seal, x_c = Fc / sigma0 = 65 um: exponent 1, F = Fc (1 - exp(-x / x_c)):
    4108.8 N at x_c, 5620.3 N at 2 x_c; exponent 2, F = Fc x / (x + x_c): 3250 N at x_c, 4875 N at
    3 x_c. Never above Fc: the break-away is the Coulomb level. The test bed's implicit Euler
    (10 nm per step) follows within 0.3 %."""
    law = _law("dahl", exponent=exponent, **NO_RATE)
    xc = FC / law.sigma0
    xs, F = _branch(law, 0.0, 1e-5, 6 * xc, 6001)
    e = exponent
    want = FC * (1.0 - np.exp(-xs / xc)) if e == 1.0 else FC * (1.0 - (1.0 + (e - 1.0) * xs / xc) ** (-1.0 / (e - 1.0)))
    assert np.abs(F - want).max() < 1e-6 * FC
    at = {1.0: ((xc, 4108.78), (2 * xc, 5620.32)), 2.0: ((xc, 3250.0), (3 * xc, 4875.0))}[e]
    for x, f in at:
        assert np.interp(x, xs, F) == pytest.approx(f, abs=0.05)
    assert F.max() < FC
    bed = testbed.PlantLaw(law)
    for _ in range(6500):            # 65 um at 10 nm per step
        f = bed.force(1e-5, 4.0, 1e-3)
    assert f == pytest.approx(at[0][1], rel=3e-3)


def test_dahl_reversal_is_twice_as_stiff_and_loops_symmetrically():
    """From steady sliding at -Fc, moving up: F = Fc (1 - 2 exp(-x / x_c)), slope 2 sigma0 at the
    reversal (the virgin curve's sigma0), F = 0 at x_c ln 2 = 45.05 um; a +-0.5 mm loop is
    symmetric (the down branch is the up one mirrored), its width 2 Fc within 1e-6."""
    law = _law("dahl", **NO_RATE)
    xc = FC / law.sigma0
    xs, up = _branch(law, -xc, 1e-5, 1e-3, 10001)
    assert np.abs(up - FC * (1.0 - 2.0 * np.exp(-xs / xc))).max() < 1e-6 * FC
    assert np.gradient(up, xs)[0] == pytest.approx(2.0 * law.sigma0, rel=2e-3)
    assert np.interp(0.0, up, xs) == pytest.approx(xc * math.log(2.0), rel=1e-4)
    assert 45.0e-6 < xc * math.log(2.0) < 45.1e-6
    z_top = up[-1] / law.sigma0
    _, down = _branch(law, z_top, -1e-5, -1e-3, 10001)   # back down over the same 1 mm
    assert np.abs(down + up).max() < 1e-6 * FC
    assert up[-1] - down[-1] == pytest.approx(2.0 * FC, rel=1e-6)


# ---------------------------------------------------------------- Bliman-Sorine, hand-checked


def test_bliman_sorine_peak_depends_on_distance_and_on_what_came_before():
    """f1 = (Fs + Fc)/2 = 8500 N, f2 = (Fs - Fc)/2 = 2000 N, d1 = 40 um, d2 = 400 um. From an
    unloaded seal F(s) = f1 (1 - e^(-s/d1)) - f2 (1 - e^(-s/d2)); after a reversal from long
    sliding F(s) = f1 (1 - 2 e^(-s/d1)) - f2 (1 - 2 e^(-s/d2)). Both peak where
    f1/d1 e^(-s/d1) = f2/d2 e^(-s/d2), s* = ln(f1 d2 / (f2 d1)) / (1/d1 - 1/d2) = 166.6 um:
    7686.7 N from rest, 8873.4 N after the reversal, both above Fc, below Fs; then F falls back
    to Fc (6513.5 N at 2 mm from rest). Initial stiffness f1/d1 - f2/d2 = 2.075e8 N/m."""
    law = _law("bliman-sorine", **NO_RATE)
    d1, d2 = law.lengths
    f1, f2 = (FS + FC) / 2, (FS - FC) / 2
    assert (d1, d2, f1, f2) == (pytest.approx(40e-6), 400e-6, 8500.0, 2000.0)
    s_star = math.log(f1 * d2 / (f2 * d1)) / (1.0 / d1 - 1.0 / d2)
    assert s_star == pytest.approx(166.645e-6, rel=1e-5)
    xs, rest = _branch(law, [0.0, 0.0], 1e-5, 2e-3, 20001)
    want = f1 * (1 - np.exp(-xs / d1)) - f2 * (1 - np.exp(-xs / d2))
    assert np.abs(rest - want).max() < 1e-6 * FC
    _, rev = _branch(law, [-d1, -d2], 1e-5, 2e-3, 20001)
    want = f1 * (1 - 2 * np.exp(-xs / d1)) - f2 * (1 - 2 * np.exp(-xs / d2))
    assert np.abs(rev - want).max() < 1e-6 * FC
    for F, peak in ((rest, 7686.70), (rev, 8873.40)):
        k = int(np.argmax(F))
        assert F[k] == pytest.approx(peak, abs=0.05)
        assert xs[k] == pytest.approx(s_star, abs=0.2e-6)
        assert FC < F[k] < FS
    assert rest[-1] == pytest.approx(6513.48, abs=0.05)
    assert np.gradient(rest, xs)[0] == pytest.approx(f1 / d1 - f2 / d2, rel=2e-3)


def test_bliman_sorine_and_dahl_are_rate_independent():
    """The state rates scale with v (dz/dt / v depends on sgn v only), so without the viscous term
    the force along a path is the same at any speed; steady sliding gives Fc(p) (+ sigma2 v) at
    0.1 and 10 mm/s alike, where LuGre weakens from Fs towards Fc."""
    rng = np.random.default_rng(5)
    for name in MORE_LAWS:
        law = _law(name, **NO_RATE)
        M = law.n_z
        z = rng.uniform(-1, 1, (50, 2)) * np.array(law.lengths) if M > 1 else rng.uniform(-1, 1, 50) * FC / law.sigma0
        v, p = rng.normal(0, 0.005, 50), rng.uniform(1e6, 9e6, 50)
        a, b = law.evaluate(v, z, p), law.evaluate(10.0 * v, z, p)
        assert np.array_equal(a.F, b.F)
        assert np.allclose(b.zdot, 10.0 * a.zdot, rtol=1e-12, atol=0.0)
        full = _law(name)
        for v in (1e-4, 1e-2):
            bed = testbed.PlantLaw(full)
            for _ in range(4000):     # 8 mm of sliding (20 ef), 2 um per step
                f = bed.force(v, 4.0, 2e-6 / v)
            assert f == pytest.approx(FC + full.sigma2.at(4.0) * v, rel=1e-6)


# ---------------------------------------------------------------- partials, plant


def _random_z(law, rng, n):
    if law.n_z > 1:
        return rng.uniform(-1.0, 1.0, (n, 2)) * np.array(law.lengths)
    return rng.uniform(-1.3, 1.3, n) * 9000.0 / law.sigma0


@pytest.mark.parametrize("name,change", [("dahl", {}), ("dahl", {"exponent": 2.5, "sigma1": 3e4}),
                                         ("bliman-sorine", {})], ids=["dahl", "dahl-e2.5", "bliman-sorine"])
def test_law_partial_derivatives_match_finite_differences(name, change):
    law = _law(name, **change)
    rng = np.random.default_rng(3)
    N, M = 300, law.n_z
    v, p = rng.normal(0, 0.005, N), rng.uniform(1e6, 10e6, N)
    z = _random_z(law, rng, N)
    out = law.evaluate(v, z, p)

    def close(got, want):
        assert np.allclose(got, want, rtol=1e-5, atol=1e-7 * np.abs(want).max() + 1e-300)

    for key, dv, dp in (("v", 1e-8, 0.0), ("p", 0.0, 1.0)):
        a, b = law.evaluate(v + dv, z, p + dp), law.evaluate(v - dv, z, p - dp)
        close(getattr(out, "F_" + key), (a.F - b.F) / (2 * (dv or dp)))
        close(getattr(out, "zd_" + key), (a.zdot - b.zdot) / (2 * (dv or dp)))
    for j in range(M):
        e = np.zeros(M)
        e[j] = 1e-11
        e = e if M > 1 else e[0]
        a, b = law.evaluate(v, z + e, p), law.evaluate(v, z - e, p)
        pick = (lambda x: x[:, j]) if M > 1 else (lambda x: x)
        close(pick(out.F_z), (a.F - b.F) / 2e-11)
        close(pick(out.zd_z), pick(a.zdot - b.zdot) / 2e-11)
    # the scalar terms (fast stepper, bed) are the vectorised law
    for i in range(0, N, 7):
        r = law.terms(v[i], z[i] if M == 1 else list(z[i]), p[i] * 1e-6, 1e-6, True)
        for got, want in zip(r, (out.F[i], out.zdot[i], out.F_v[i], out.F_z[i], out.F_p[i], out.zd_v[i],
                                 out.zd_z[i], out.zd_p[i])):
            assert np.allclose(got, want, rtol=1e-9, atol=1e-12 * (abs(np.max(np.abs(want))) + 1e-30))


def _short_doc(scenarios_dir, table):
    path = scenarios_dir / "short-test.toml"
    doc = tomllib.loads(path.read_text())
    doc["plant"]["friction"] = table
    return doc, path


def _table(name, scale=(1.0, 1.2, 0.9, 1.0)):
    t = example_table(name)
    t["force_scale"] = list(scale)
    return t


@pytest.mark.parametrize("name", MORE_LAWS)
def test_plant_jacobian_matches_finite_differences(scenarios_dir, name):
    sc = build(*_short_doc(scenarios_dir, _table(name)))
    p, u = sc.plant, sc.inputs
    assert p.nz == law_nz(name) and p.size == 3 + 4 * p.n + p.n * p.nz
    rng = np.random.default_rng(1)
    sc_ = state_scale(p)
    for _ in range(3):
        y = p.rest_state(u)
        y[p.iv] = rng.normal(0, 0.004, p.n)
        y[p.iz] = _random_z(p.friction, rng, p.n).ravel()
        y[p.ip] += rng.normal(0, 1e5, p.n)
        y[p.iq] = rng.normal(0, 1e-4, p.n)
        y[0] += 1e-3      # cage off its rest (a finite-difference step in rd of 1e-12 m/s is noise)
        y[1] = 0.01
        f, J = p.rhs(u, 20, y, True)
        step = np.abs(y) * 1e-7 + 1e-12
        fd = np.empty_like(J)
        for j in range(p.size):
            e = np.zeros(p.size)
            e[j] = step[j]
            fd[:, j] = (p.rhs(u, 20, y + e) - p.rhs(u, 20, y - e)) / (2 * step[j])
        Js, fds = J * sc_ / sc_[:, None], fd * sc_ / sc_[:, None]
        row = np.abs(fds).max(axis=1, keepdims=True) + 1e-30
        assert np.all(np.abs(Js - fds) <= 1e-4 * np.abs(fds) + 1e-6 * row)


def law_nz(name):
    return 2 if name == "bliman-sorine" else 1


def _dense_run(sc):
    p, u = sc.plant, sc.inputs
    Y = integrate(p, u, sc.step_s, p.rest_state(u), method="bdf2")
    out = p.outputs(u, Y)
    out["t"] = u.t
    return out


@pytest.fixture(scope="module", params=MORE_LAWS)
def halving_run(request, scenarios_dir):
    """short-test (2 t loaded, a 3 m creep; 2.5 ms steps) with each law (force_scale 1, 1.2, 0.9, 1)
    by the dense BDF2, and again with every step halved."""
    doc, path = _short_doc(scenarios_dir, _table(request.param))
    full = build(doc, path)
    half = build(halved_doc(doc, full), path)
    return request.param, full, _dense_run(full), _dense_run(half)


def test_a_plant_run_stays_within_the_laws_bounds(halving_run):
    """The truth check passes (|F| <= 1.2 force_scale (Fs(p) + sigma2 |v|); for Dahl Fs is Fc); in
    fact |F| stays within 0.83 (Dahl) / 0.68 of it, the oil pressure above 5.8 MPa, Bliman-Sorine's
    states within 0.9 of their lengths; at the final rest
    T = p_cav A + F, and the seals hold a share of the load."""
    name, sc, a, _ = halving_run
    law, p = sc.plant.friction, sc.plant
    assert sc.hidden["friction_law"] == name
    check_truth(law, a, a["t"])
    pm = np.maximum(a["p_cav_Pa"], 0.0) * 1e-6
    bound = np.asarray(law.force_scale) * (law.Fs.at(pm) + law.sigma2.at(pm) * np.abs(a["piston_v_m_s"]))
    assert (np.abs(a["friction_N"]) / bound).max() < 1.01
    assert a["p_cav_Pa"].min() > 5e6
    k = len(a["t"]) - 1
    assert np.allclose(a["tension_N"][k], a["p_cav_Pa"][k] * p.A + a["friction_N"][k], atol=5.0)
    assert np.abs(a["friction_N"][k]).min() > 500.0
    assert a["z_m"].shape == (len(a["t"]), p.n)
    if name == "bliman-sorine":
        assert a["z_elements_m"].shape == (len(a["t"]), p.n, 2)
        assert np.all(np.abs(a["z_elements_m"]) <= np.array(law.lengths) * (1 + 1e-6))


def test_halving_the_step_changes_tensions_and_friction_by_less_than_0_1_percent_of_rated(halving_run):
    """As test_convergence for LuGre (there by the fast stepper): halving every step moves rope
    tensions by 5.5 N (Dahl) / 5.7 N (Bliman-Sorine), friction by 7.2 / 7.1 N, against 80 N (0.1 % of
    the rated 80 kN; LuGre by the same dense BDF2: 5.5 / 6.1 N); the pistons by 0.23 / 0.18 um; x stays
    the integral of v within 0.011 um."""
    name, sc, a, b = halving_run
    idx = np.searchsorted(b["t"], a["t"])
    assert np.allclose(b["t"][idx], a["t"], atol=1e-12)
    rated = sc.rated_rope_tension_N
    dT = np.abs(a["tension_N"] - b["tension_N"][idx]).max()
    dF = np.abs(a["friction_N"] - b["friction_N"][idx]).max()
    assert 0.0 < dT < 0.001 * rated and 0.0 < dF < 0.001 * rated, (dT, dF)
    assert np.ptp(a["friction_N"]) > 1000.0 and np.ptp(a["tension_N"]) > 1000.0
    assert np.abs(a["piston_x_m"] - b["piston_x_m"][idx]).max() < 1e-6
    for r in (a, b):
        assert np.abs(x_minus_integral_of_v(r["t"], r["piston_x_m"], r["piston_v_m_s"])).max() < 1e-6


@pytest.mark.parametrize("name", MORE_LAWS)
def test_fast_stepper_is_the_dense_model(scenarios_dir, name):
    """The fast stepper's right-hand side, block solve and BDF2 run are the dense model's."""
    sc = build(*_short_doc(scenarios_dir, _table(name)))
    p, u = sc.plant, sc.inputs
    st = Stepper(p, u)
    rng = np.random.default_rng(2)
    for _ in range(3):
        y = p.rest_state(u)
        y[p.iv] = rng.normal(0, 0.004, p.n)
        y[p.iz] = _random_z(p.friction, rng, p.n).ravel()
        f, J = p.rhs(u, 10, y, True)
        fk, jac = st.rhs(10, list(y), True)
        assert np.allclose(fk, f, rtol=1e-10, atol=1e-300)
        b = rng.normal(size=p.size) * (np.abs(f) + 1)
        dense = np.linalg.solve(np.eye(p.size) - 0.01 * J, b)
        fast = np.array(st.solve(st.factor(jac, 0.01), list(b)))
        assert np.allclose(fast, dense, rtol=1e-8, atol=1e-12 * np.abs(dense).max())
    k = len(u.t) // 3
    y0 = p.rest_state(u)
    dense = integrate(p, u.take(np.arange(k)), sc.step_s, y0, method="bdf2")
    fast = integrate_fast(p, u, y0, list(range(k)), method="bdf2")
    assert np.allclose(fast, dense, rtol=1e-6, atol=1e-8 * np.abs(dense).max(axis=0))


# ---------------------------------------------------------------- tables, force_scale, population


def test_example_tables_have_the_field_trip_magnitudes():
    """Dahl: Fc and sigma2 lines only, sigma0 = 1e8 (LuGre's), 80 % of Fc = 8 kN after
    x_c ln 5 = 128.8 um; Bliman-Sorine: Fs, Fc, sigma2, 80 % of Fc after 20..150 um from rest."""
    d, b = example_table("dahl"), example_table("bliman-sorine")
    assert set(d) == {"law", "Fc", "sigma2", "sigma0", "exponent"}
    assert set(b) == {"law", "Fs", "Fc", "sigma2", "eta", "ef"}
    lug = example_table("lugre")
    assert d["Fc"] == b["Fc"] == lug["Fc"] and b["Fs"] == lug["Fs"] and d["sigma2"] == lug["sigma2"]
    assert isinstance(_law("dahl"), Dahl) and isinstance(_law("bliman-sorine"), BlimanSorine)
    for name in MORE_LAWS:
        law = _law(name)
        pm = (8000.0 - law.Fc.intercept) / law.Fc.slope
        bed, x, h = testbed.PlantLaw(law), 0.0, 1e-3
        while bed.force(1e-5, pm, h) - law.sigma2.at(pm) * 1e-5 < 0.8 * 8000.0:
            x += 1e-5 * h
        assert 20e-6 < x < 150e-6
        if name == "dahl":
            assert x == pytest.approx(80e-6 * math.log(5.0), rel=5e-3)


def test_the_catalogue_keeps_the_four_and_adds_two():
    assert LAWS == ("lugre", "coulomb-stribeck", "maxwell-slip", "elasto-plastic")
    assert ALL_LAWS == LAWS + ("dahl", "bliman-sorine")
    with pytest.raises(ValueError, match="law"):
        example_table("bouc-wen")


BAD = [
    ("dahl", {"exponent": 0.5}, "plant.friction.exponent"),
    ("dahl", {"exponent": 5.0}, "plant.friction.exponent"),
    ("dahl", {"sigma0": 0.0}, "plant.friction.sigma0"),
    ("dahl", {"sigma1": -1.0}, "plant.friction.sigma1"),
    ("dahl", {"Fc": {"intercept": 0.0, "slope": 1200.0}}, "plant.friction.Fc.intercept"),
    ("dahl", {"Fs": {"intercept": 2500.0, "slope": 2000.0}}, "plant.friction.Fs"),
    ("dahl", {"vs": {"intercept": 0.004}}, "plant.friction.vs"),
    ("dahl", {"force_scale": [1.0, 0.0, 1.0, 1.0]}, "plant.friction.force_scale[1]"),
    ("bliman-sorine", {"eta": 1.0}, "plant.friction.eta"),
    ("bliman-sorine", {"eta": 0.0}, "plant.friction.eta"),
    ("bliman-sorine", {"ef": -1e-4}, "plant.friction.ef"),
    ("bliman-sorine", {"vs": {"intercept": 0.004}}, "plant.friction.vs"),
    ("bliman-sorine", {"sigma0": 1e8}, "plant.friction.sigma0"),
    ("bliman-sorine", {"force_scale": [1.0, 1.0]}, "plant.friction.force_scale"),
    ("bliman-sorine", {"law": "bouc-wen"}, "plant.friction.law"),
]


@pytest.mark.parametrize("name,change,field", BAD, ids=[b[2] + "-" + b[0] for b in BAD])
def test_from_table_refuses_bad_fields_naming_them(name, change, field):
    t = example_table(name)
    t.update(change)
    with pytest.raises(ScenarioError) as e:
        from_table(t, "plant.friction", n_ropes=4)
    assert str(e.value).startswith(field + ":"), str(e.value)


@pytest.mark.parametrize("name", ["dahl", "bliman-sorine"])
def test_from_table_names_a_missing_field(name):
    t = example_table(name)
    del t["sigma0" if name == "dahl" else "Fs"]
    with pytest.raises(ScenarioError, match=r"^plant\.friction\.(sigma0|Fs): missing"):
        from_table(t, "plant.friction")


@pytest.mark.parametrize("name", MORE_LAWS)
def test_force_scale_scales_the_force_and_not_the_state(name):
    base = _law(name, exponent=1.7) if name == "dahl" else _law(name)
    scale = [1.0, 1.4, 0.7, 2.0]
    scaled = from_table({**example_table(name), **({"exponent": 1.7} if name == "dahl" else {}),
                         "force_scale": scale}, "plant.friction")
    rng = np.random.default_rng(4)
    v, p = rng.normal(0, 0.004, (30, 4)), rng.uniform(1e6, 10e6, (30, 4))
    z = rng.normal(0, 4e-5, (30, 4) + ((base.n_z,) if base.n_z > 1 else ()))
    a, b = base.evaluate(v, z, p), scaled.evaluate(v, z, p)
    sz = np.array(scale) if base.n_z == 1 else np.array(scale)[:, None]
    assert np.allclose(b.F, a.F * scale, rtol=1e-12) and np.allclose(b.F_p, a.F_p * scale, rtol=1e-12)
    assert np.allclose(b.F_z, a.F_z * sz, rtol=1e-12)
    assert np.array_equal(b.zdot, a.zdot) and np.array_equal(b.zd_z, a.zd_z)
    for i in range(4):
        own = scaled.rope_seal(i)
        assert own.force_scale is None
        assert np.allclose(own.evaluate(v[:, i], z[:, i], p[:, i]).F, b.F[:, i], rtol=1e-12)


def test_population_draws_the_held_out_laws_only_on_request():
    """LAWS (what `draw` picks) is unchanged; a drawn hoist's seal in a held-out law keeps its
    force level, slopes, rope scales and stiffness, its own parameters scattered (Dahl exponent
    1-2; Bliman-Sorine eta 0.05-0.2, ef 0.1-1.6 mm)."""
    assert P.LAWS == ("lugre", "maxwell-slip", "elasto-plastic")
    assert set(P.HELD_OUT_LAWS) == set(MORE_LAWS) and not set(P.HELD_OUT_LAWS) & set(P.LAWS)
    exps, etas = [], []
    for seed in P.TUNING_SEEDS:
        h = P.draw(seed)
        assert h.law in P.LAWS
        for law in P.HELD_OUT_LAWS:
            t = P.seal_table(law, h.draws, h.friction["force_scale"])
            f = from_table(t, "plant.friction", n_ropes=4)
            assert f.name == law and list(f.force_scale) == h.friction["force_scale"]
            assert t["Fc"] == P._scale_line(example_table(law)["Fc"], h.draws["force_level"], h.draws["slope_ratio"])
            if law == "dahl":
                assert 1.0 <= f.exponent <= 2.0
                assert f.sigma0 == pytest.approx(1e8 * h.draws["force_level"] * h.draws["stiffness_scale"])
                exps.append(f.exponent)
            else:
                assert 0.05 <= f.eta <= 0.2 and 0.1e-3 <= f.ef <= 1.6e-3
                etas.append(f.eta)
    assert np.ptp(exps) > 0.3 and np.ptp(etas) > 0.05
