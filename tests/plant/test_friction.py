"""Friction laws: steady sliding force, sign, presliding, and the partial derivatives the solver uses."""
import numpy as np
import pytest

from ropemon.lab.plant.friction import CoulombStribeck, Line, LuGre

LUGRE = LuGre(Fs=Line(2500.0, 2000.0), Fc=Line(1700.0, 1200.0), vs=Line(0.004, -0.0002),
              sigma2=Line(20000.0, 2000.0), sigma0=1e8, sigma1=5e4)
CS = CoulombStribeck(Fs=Line(2500.0, 2000.0), Fc=Line(1700.0, 1200.0), vs=Line(0.004, -0.0002),
                     sigma2=Line(20000.0, 2000.0), v_threshold=1e-4)


@pytest.mark.parametrize("v", [-0.05, -0.002, 0.0005, 0.01])
@pytest.mark.parametrize("p_pa", [0.0, 5e6])
def test_lugre_steady_sliding_is_the_stribeck_curve(v, p_pa):
    pm = p_pa * 1e-6
    g = LUGRE.Fc.at(pm) + (LUGRE.Fs.at(pm) - LUGRE.Fc.at(pm)) * np.exp(-(v / LUGRE.vs.at(pm)) ** 2)
    z_ss = np.sign(v) * g / LUGRE.sigma0
    out = LUGRE.evaluate(np.array([v]), np.array([z_ss]), np.array([p_pa]))
    assert out.zdot[0] == pytest.approx(0.0, abs=1e-12)
    assert out.F[0] == pytest.approx(np.sign(v) * g + LUGRE.sigma2.at(pm) * v, rel=1e-12)


def test_friction_grows_with_pressure_as_in_the_paper():
    v = np.array([0.01])
    lo = CS.evaluate(v, np.zeros(1), np.array([1e6])).F[0]
    hi = CS.evaluate(v, np.zeros(1), np.array([10e6])).F[0]
    assert hi > lo > 0


def _fd(law, v, z, p):
    out = law.evaluate(v, z, p)
    hv, hz, hp = 1e-7, 1e-10, 1.0
    d = {}
    for name, dv, dz, dp in (("v", hv, 0, 0), ("z", 0, hz, 0), ("p", 0, 0, hp)):
        a = law.evaluate(v + dv, z + dz, p + dp)
        b = law.evaluate(v - dv, z - dz, p - dp)
        step = 2 * (dv or dz or dp)
        d["F_" + name] = (a.F - b.F) / step
        d["zd_" + name] = (a.zdot - b.zdot) / step
    return out, d


@pytest.mark.parametrize("law", [LUGRE, CS], ids=["lugre", "coulomb-stribeck"])
def test_partial_derivatives_match_finite_differences(law):
    rng = np.random.default_rng(3)
    v = rng.normal(0, 0.005, 50)
    z = rng.normal(0, 3e-5, 50)
    p = rng.uniform(1e6, 10e6, 50)
    out, d = _fd(law, v, z, p)
    for key, val in d.items():
        got = getattr(out, key)
        assert np.allclose(got, val, rtol=1e-4, atol=1e-6 * (np.abs(val).max() + 1)), key
