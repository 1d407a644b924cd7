"""The static estimators and the LuGre config variants, checked by hand."""
import numpy as np
import pytest

from ropemon.lab import estimators as est

FRICTION = {
    "Fs": {"slope": 100.0, "intercept": 1000.0},
    "Fc": {"slope": 50.0, "intercept": 500.0},
    "vs": {"slope": -0.001, "intercept": 0.01},
    "sigma2": {"slope": 1000.0, "intercept": 10000.0},
    "sigma0": 1e7, "sigma1": 1e4,
}
PHYS = {"cylinder_area_m2": [0.01, 0.02], "friction": FRICTION,
        "loss": {"temps_C": [0, 40], "flow_m3_s": [0, 1e-3], "dp_Pa": [[[0, 1e5], [0, 5e4]]] * 2}}


def sig(p_pa, v, dp):
    return est.Signals(np.array(p_pa, float), np.array(v, float), np.array(dp, float))


def test_names():
    assert len(est.ESTIMATORS) == 12
    assert est.FULL_COMPENSATION in est.ESTIMATORS and "raw" in est.ESTIMATORS and "stribeck+loss" in est.ESTIMATORS


def test_raw_and_loss():
    s = sig([[2e6, 4e6]], [[0.01, -0.01]], [[1e4, -2e4]])
    assert est.static_estimate_n("raw", PHYS, s) == pytest.approx(np.array([[2e4, 8e4]]))
    assert est.static_estimate_n("raw+loss", PHYS, s) == pytest.approx(np.array([[2.01e6 * 0.01, 3.98e6 * 0.02]]))


def test_coulomb_and_viscous_at_2_mpa():
    # at 2 MPa: Fc = 600 N, sigma2 = 12000 N s/m
    s = sig([[2e6, 2e6]], [[0.01, -0.01]], [[0.0, 0.0]])
    assert est.static_estimate_n("coulomb", PHYS, s) == pytest.approx(np.array([[2e4 + 600, 4e4 - 600]]))
    assert est.static_estimate_n("coulomb-viscous", PHYS, s) == pytest.approx(np.array([[2e4 + 720, 4e4 - 720]]))


def test_stribeck_at_zero_and_high_speed():
    # at 2 MPa: Fs = 1200, Fc = 600, vs = 0.008
    v = np.array([[0.008, 1.0]])
    s = sig([[2e6, 2e6]], v, [[0.0, 0.0]])
    f = est.static_estimate_n("stribeck", PHYS, s) - [[2e4, 4e4]]
    assert f[0, 0] == pytest.approx(600 + 600 * np.exp(-1) + 12000 * 0.008)
    assert f[0, 1] == pytest.approx(600 + 12000 * 1.0)


def test_static_laws_read_no_friction_inside_the_deadband():
    s = sig([[2e6, 2e6]], [[0.5 * est.VELOCITY_DEADBAND_M_S, 0.0]], [[0.0, 0.0]])
    for law in ("coulomb", "stribeck"):
        assert est.static_estimate_n(law, PHYS, s)[0, 1] == pytest.approx(4e4)
        assert abs(est.static_estimate_n(law, PHYS, s)[0, 0] - 2e4) < 1.0  # only sigma2 v


def test_unknown_estimator_refused():
    with pytest.raises(ValueError, match="unknown"):
        est.static_estimate_n("karnopp", PHYS, sig([[0, 0]], [[0, 0]], [[0, 0]]))
    with pytest.raises(ValueError, match="unknown"):
        est.static_estimate_n("raw+filter", PHYS, sig([[0, 0]], [[0, 0]], [[0, 0]]))


def test_lugre_const_freezes_lines_at_calibration_pressure():
    c = est.lugre_const_physical(PHYS, 6.0)
    assert c["friction"]["Fs"] == {"slope": 0.0, "intercept": 1600.0}
    assert c["friction"]["vs"]["intercept"] == pytest.approx(0.004)
    assert c["friction"]["sigma0"] == 1e7
    assert PHYS["friction"]["Fs"]["slope"] == 100.0  # the original is untouched


def test_no_loss_zeroes_the_table_only():
    c = est.no_loss_physical(PHYS)
    assert np.all(np.asarray(c["loss"]["dp_Pa"]) == 0) and np.asarray(c["loss"]["dp_Pa"]).shape == (2, 2, 2)
    assert c["loss"]["flow_m3_s"] == PHYS["loss"]["flow_m3_s"]
    assert np.asarray(PHYS["loss"]["dp_Pa"]).max() == 1e5
