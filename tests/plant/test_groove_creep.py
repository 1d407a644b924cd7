"""Ropes that pay out unequally (groove_creep) part through a wind, and the seals hold the difference."""
import tomllib

import numpy as np

from ropemon.lab.plant.run import simulate
from ropemon.lab.plant.scenario import build


def _field_trip(scenarios_dir, creep):
    doc = tomllib.loads((scenarios_dir / "paper-field-trip.toml").read_text())
    doc["plant"]["ropes"]["groove_creep"] = creep
    return build(doc, scenarios_dir / "paper-field-trip.toml", 1)


def test_each_rope_is_longer_by_its_creep_times_the_wheels_travel(scenarios_dir):
    creep = [1.0e-5, -1.0e-5, 0.0, 5.0e-6]
    sc = _field_trip(scenarios_dir, creep)
    u = sc.inputs
    travel = u.s_wheel - u.s_wheel[0]
    # the rope's extra length enters the tension as -y: y = -creep x travel
    np.testing.assert_allclose(u.y_load, -travel[:, None] * np.array(creep), atol=1e-12)
    np.testing.assert_allclose(u.ydot_load, -u.u_wheel[:, None] * np.array(creep), atol=1e-12)
    assert abs(travel.min()) > 800.0  # the wind from the bottom to the pithead: ~8 mm on rope 1
    assert u.y_load[0].tolist() == [0.0, 0.0, 0.0, 0.0]


def test_parting_ropes_end_the_wind_unequal_where_equal_ropes_do_not(scenarios_dir):
    def spread_at_top(creep):
        res = simulate(_field_trip(scenarios_dir, creep))
        t = np.asarray(res.truth["tension_N"])
        top = np.asarray(res.truth["cage_depth_m"]) < 3.0
        dev = t[top] / t[top].mean(axis=1, keepdims=True) - 1.0
        return float(np.abs(dev).max())

    assert spread_at_top([1.2e-5, -1.2e-5, 1.2e-5, -1.2e-5]) > spread_at_top([0.0] * 4) + 0.02
