"""Oil properties (Walther) and the S-curve trip motion."""
import numpy as np
import pytest

from ropemon.lab.plant.motion import Timeline, scurve_pieces
from ropemon.commission.oil import Oil


def test_vg46_viscosity_through_its_grade_points_and_falls_with_temperature():
    oil = Oil.grade(46)
    assert oil.nu_m2_s(40.0) * 1e6 == pytest.approx(46.0, rel=1e-9)
    assert oil.nu_m2_s(100.0) * 1e6 == pytest.approx(6.8, rel=1e-9)
    nus = [oil.nu_m2_s(t) for t in (0, 10, 20, 30, 40)]
    assert all(a > b for a, b in zip(nus, nus[1:]))
    # a winter shaft: roughly tenfold between 0 and 40 C (domain brief: ~471 vs 41 cSt)
    assert 8 < nus[0] / nus[-1] < 15
    assert oil.rho_kg_m3(0.0) > oil.rho_kg_m3(40.0)


def test_unknown_grade_needs_its_100C_viscosity():
    with pytest.raises(ValueError, match="iso_vg"):
        Oil.grade(1000)


@pytest.mark.parametrize("distance", [-806.0, 806.0, 3.0, -0.5])
def test_scurve_reaches_the_target_within_its_limits(distance):
    v, a, j = 10.0, 0.75, 0.5
    tl = Timeline(400.0)
    tl.rest(1.0)
    tl.move(distance, v, a, j)
    tl.rest(1.0)
    t = np.linspace(0, tl.duration_s, 200_001)
    s, u, acc = tl.evaluate(t)
    assert s[0] == 400.0 and s[-1] == pytest.approx(400.0 + distance, abs=1e-6)
    assert np.abs(u).max() <= v + 1e-9
    assert np.abs(acc).max() <= a + 1e-9
    assert np.abs(np.diff(acc) / np.diff(t)).max() <= j * (1 + 1e-6)
    # speed is the derivative of position, acceleration of speed
    assert np.allclose(np.gradient(s, t)[1:-1], u[1:-1], atol=1e-3)
    assert u[-1] == 0.0 and acc[-1] == 0.0
    # depth positive downwards: a wind up (negative distance) has negative speed
    assert np.sign(u[np.abs(u).argmax()]) == np.sign(distance)


def test_short_move_never_reaches_full_speed():
    pieces = scurve_pieces(1.0, 10.0, 0.75, 0.5)
    tl = Timeline(0.0, pieces)
    _, u, _ = tl.evaluate(np.linspace(0, tl.duration_s, 10001))
    assert u.max() < 10.0
