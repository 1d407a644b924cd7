"""Step convergence: halving the step changes rope tensions by < 0.1 % of rated (short-test; the
field trip's figure is printed by `ropemon bench plant` and kept in docs/benchmarks.md)."""
import numpy as np

from ropemon.plant.convergence import halving_difference
from ropemon.plant.scenario import load_scenario


def test_halving_the_step_changes_tensions_by_less_than_0_1_percent_of_rated(scenarios_dir):
    sc = load_scenario(scenarios_dir / "short-test.toml")
    d = halving_difference(sc.path)
    assert d["max_dT_N"] < 0.001 * sc.rated_rope_tension_N
    # and the comparison is not empty: the runs do move and differ a little
    assert d["tension_range_N"] > 1000.0
    assert d["max_dT_N"] > 0.0
