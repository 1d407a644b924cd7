"""The product's float seal model (ropemon.commission.seal), by hand-checkable numbers."""
import math

import numpy as np
import pytest

from ropemon.commission import seal

# At 2 MPa: Fs = 3000 N, Fc = 2000 N, vs = 4 mm/s, sigma2 = 25000 N s/m.
FR = {"Fs": {"intercept": 2000.0, "slope": 500.0}, "Fc": {"intercept": 1000.0, "slope": 500.0},
      "vs": {"intercept": 0.006, "slope": -0.001}, "sigma2": {"intercept": 20000.0, "slope": 2500.0},
      "sigma0": 1e7, "sigma1": 1e4}


def test_the_pressure_lines():
    assert seal.lines_at(FR, 2.0) == pytest.approx((3000.0, 2000.0, 0.004, 25000.0))
    assert seal.line_at(FR, "Fs", 0.0) == 2000.0
    assert seal.line_at(FR, "Fs", np.array([0.0, 4.0])) == pytest.approx([2000.0, 4000.0])


def test_stribeck_curve_from_fs_at_rest_to_fc_sliding_fast():
    fs, fc, vs, _ = seal.lines_at(FR, 2.0)
    assert seal.g(0.0, fs, fc, vs) == 3000.0
    assert seal.g(vs, fs, fc, vs) == pytest.approx(2000.0 + 1000.0 / math.e)    # 2367.88 N
    assert seal.g(-vs, fs, fc, vs) == seal.g(vs, fs, fc, vs)
    assert seal.g(1.0, fs, fc, vs) == 2000.0                                   # exp(-62500) = 0


def test_steady_force_has_the_sign_of_v():
    lines = seal.lines_at(FR, 2.0)
    assert seal.steady_force(0.0, *lines) == 0.0
    assert seal.steady_force(0.004, *lines) == pytest.approx(2000.0 + 1000.0 / math.e + 100.0)
    assert seal.steady_force(-0.004, *lines) == pytest.approx(-(2000.0 + 1000.0 / math.e + 100.0))


def test_vectorised_equals_scalar():
    v = np.array([-0.02, -0.004, -1e-4, 0.0, 0.001, 0.004, 0.05])
    p = np.array([0.0, 1.0, 2.0, 3.0, 5.0, 2.0, 4.0])
    lines = seal.lines_at(FR, p)
    scalar = [seal.steady_force(float(vi), *seal.lines_at(FR, float(pi))) for vi, pi in zip(v, p)]
    assert seal.steady_force(v, *lines) == pytest.approx(scalar, rel=1e-15, abs=0.0)
    g_scalar = [seal.g(float(vi), *seal.lines_at(FR, float(pi))[:3]) for vi, pi in zip(v, p)]
    assert seal.g(v, *lines[:3]) == pytest.approx(g_scalar, rel=1e-15, abs=0.0)


def test_lugre_slides_into_the_steady_force_and_holds_it_at_rest():
    law = seal.LuGre(FR)
    for _ in range(2000):      # 2 s at 4 mm/s: 8 mm, 34 times the bristles' g / sigma0 = 0.24 mm
        law.force(0.004, 2.0, 1e-3)
    assert law.force(0.004, 2.0, 0.0) == pytest.approx(2000.0 + 1000.0 / math.e + 100.0, rel=1e-12)
    law.force(0.0, 2.0, 1.0)   # the piston stops: z stays, the seal holds sigma0 z = g(4 mm/s)
    assert law.force(0.0, 2.0, 0.0) == pytest.approx(2000.0 + 1000.0 / math.e, rel=1e-12)


def test_lugre_presliding_is_elastic_at_first():
    law = seal.LuGre(FR)
    law.force(1e-4, 2.0, 1e-3)  # 0.1 um from rest: sigma0 z = 1 N, far below Fs
    assert FR["sigma0"] * law.z == pytest.approx(1.0, rel=1e-3)


def test_bristle_force_is_the_same_update_over_arrays():
    assert seal.bristle_force(np.array([1.0, 1.0]), np.array([0.5, 0.5]), 0.0).tolist() == [0.5, 0.75]
    law = seal.LuGre(FR)
    v = 0.004 * np.sin(np.linspace(0.0, 6.0, 300))
    h = 1e-3
    z = []
    for vi in v.tolist():
        law.force(vi, 2.0, h)
        z.append(law.z)
    fs, fc, vs, _ = seal.lines_at(FR, 2.0)
    gv = seal.g(v, fs, fc, vs)
    w = seal.bristle_force(np.sign(v) * gv, np.exp(-FR["sigma0"] * np.abs(v) / gv * h), 0.0)
    assert w == pytest.approx(FR["sigma0"] * np.array(z), rel=1e-9, abs=1e-9)
