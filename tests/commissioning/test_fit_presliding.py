"""fit-friction's sigma0 on seals that are not LuGre: the reversals' initial slope dF/dx (the
seal's elastic stiffness at a turn) where the reversals start elastically, the LuGre simulation
where they start as LuGre's do (LuGre fits unchanged), also with reversals too fast for the
simulation's slow stretches (the evaluation's 4 s bed for non-LuGre seals)."""
from __future__ import annotations

from pathlib import Path

import pytest

from ropemon.commission import calibrate
from ropemon.lab import testbed
from ropemon.lab.plant.friction import example_table

from test_fit_residual import seal_file

PRESSURES = (2.0, 5.0, 8.0, 11.0)
SLOW_VS = {"intercept": 0.002, "slope": -0.00005}   # reversals of the 4 s bed exceed vs/4


def fit_law(tmp: Path, table: dict, period_s: float = 4.0) -> dict:
    params, factory = testbed.scenario_seal(seal_file(tmp / "seal.toml", table))
    data = testbed.run(params, law_factory=factory, pressures_MPa=PRESSURES, seed=7, presliding_period_s=period_s)
    testbed.write_csv(tmp / "bed.csv", data)
    doc, _levels, _warnings = calibrate.fit(calibrate.read_csv(tmp / "bed.csv"))
    return doc


def initial_stiffness(table: dict) -> float:
    """The law's dF/dx right after a reversal: sigma0 (elasto-plastic), the elements' sum (Maxwell-slip)."""
    return float(table["sigma0"]) if "sigma0" in table else float(sum(table["k"]))


@pytest.mark.parametrize("law", ["elasto-plastic", "maxwell-slip"])
@pytest.mark.parametrize("slow_vs", [False, True], ids=["bed-vs", "slow-vs"])
def test_sigma0_of_a_non_lugre_seal_is_its_initial_stiffness(tmp_path, law, slow_vs):
    table = example_table(law)
    if slow_vs:  # before: no slow stretch of 2 s, sigma0 fell back to the default
        table["vs"] = dict(SLOW_VS)
    doc = fit_law(tmp_path, table)
    pre = doc["presliding"]
    assert pre["source"] == "fitted sigma0, default sigma1"
    assert pre["method"] == "initial-slope (elastic start)"
    assert pre["initial_slope"]["lugre_shape"] is False
    assert pre["initial_slope"]["turns"] >= 12
    assert doc["sigma0"] == pytest.approx(initial_stiffness(table), rel=0.05)
    assert doc["sigma1"] == pytest.approx(doc["sigma0"] * calibrate.DEFAULT_DAMPING_TIME_S)
    assert any("initial slope" in w and "not a LuGre seal" in w for w in doc["warnings"])


def test_on_a_lugre_bed_the_simulation_is_kept(tmp_path):
    """The LuGre seal's reversals start as LuGre's exponential (initial slope 2 sigma0 after
    sliding); the simulation's sigma0 is used as before, within 10 % (it is within 0.2 %)."""
    data = testbed.run(testbed.PAPER_SEAL, pressures_MPa=PRESSURES, seed=7,
                       presliding_period_s=testbed.presliding_period_s(testbed.PAPER_SEAL))
    testbed.write_csv(tmp_path / "bed.csv", data)
    doc, _levels, _warnings = calibrate.fit(calibrate.read_csv(tmp_path / "bed.csv"))
    pre = doc["presliding"]
    assert pre["method"] == "lugre-simulation" and pre["source"].startswith("fitted")
    assert doc["sigma0"] == pre["sigma0_fit"]
    assert doc["sigma0"] == pytest.approx(testbed.PAPER_SEAL["sigma0"], rel=0.10)
    sl = pre["initial_slope"]
    assert sl["lugre_shape"] is True
    assert sl["sigma0"] == pytest.approx(2 * testbed.PAPER_SEAL["sigma0"], rel=0.15)  # LuGre's 2 sigma0 at a turn
    assert sl["lugre_sigma0"] == pytest.approx(testbed.PAPER_SEAL["sigma0"], rel=0.10)


def test_a_lugre_seal_with_reversals_too_fast_for_the_simulation_gets_half_its_initial_slope(tmp_path):
    table = example_table("lugre")
    table["vs"] = dict(SLOW_VS)
    doc = fit_law(tmp_path, table)
    pre = doc["presliding"]
    assert pre["method"] == "initial-slope (LuGre start)"
    assert pre["source"] == "fitted sigma0, default sigma1"
    assert doc["sigma0"] == pytest.approx(table["sigma0"], rel=0.15)
