"""The guard that keeps a broken truth from being written or scored (`run.check_truth`)."""
from __future__ import annotations

import numpy as np
import pytest

from ropemon.lab.plant.friction import example_table, from_table
from ropemon.lab.plant.run import FRICTION_TOL, TruthError, check_truth


def _truth(law, n=200, ropes=4):
    """A plausible truth: pressures 3 MPa, pistons sliding at 2 mm/s, friction at 0.9 of
    force_scale (Fs(p) + sigma2(p) |v|)."""
    t = np.arange(n) * 0.005
    p = np.full((n, ropes), 3e6)
    v = np.full((n, ropes), 2e-3) * np.where(np.arange(n) % 40 < 20, 1.0, -1.0)[:, None]
    scale = np.ones(ropes) if law.force_scale is None else np.asarray(law.force_scale)
    F = 0.9 * scale * (law.Fs.at(3.0) + law.sigma2.at(3.0) * np.abs(v)) * np.sign(v)
    return t, {"friction_N": F, "p_cav_Pa": p, "piston_v_m_s": v}


def _law(name, scale=(0.9, 1.1, 1.0, 1.2)):
    t = example_table(name)
    t["force_scale"] = list(scale)
    return from_table(t, "plant.friction")


@pytest.mark.parametrize("name", ["lugre", "coulomb-stribeck", "maxwell-slip", "elasto-plastic"])
def test_a_sound_truth_passes(name):
    law = _law(name)
    t, tr = _truth(law)
    check_truth(law, tr, t)


def test_a_runaway_seal_friction_is_refused_naming_rope_time_and_ratio():
    law = _law("elasto-plastic")
    t, tr = _truth(law)
    tr["friction_N"][123, 2] *= 5.0          # 4.5 x the bound on rope 3 (from 1) at 0.615 s
    with pytest.raises(TruthError, match=r"rope 3: seal friction .* at t = 0\.615 s is 4\.5 x"):
        check_truth(law, tr, t)
    # the bound is force_scale times the law's line: rope 4 (scale 1.2) may carry 1.2 x rope 3's force
    t, tr = _truth(law)
    tr["friction_N"][50, 2] = tr["friction_N"][50, 3] * 1.2   # 1.3 x rope 3's bound, 0.9 x rope 4's x 1.2
    with pytest.raises(TruthError, match="rope 3"):
        check_truth(law, tr, t)


def test_the_friction_tolerance_is_the_stated_one():
    law = _law("lugre")
    t, tr = _truth(law)
    tr["friction_N"] *= (FRICTION_TOL - 1e-3) / 0.9
    check_truth(law, tr, t)
    tr["friction_N"] *= (FRICTION_TOL + 2e-3) / (FRICTION_TOL - 1e-3)
    with pytest.raises(TruthError):
        check_truth(law, tr, t)


def test_the_bound_clamps_the_pressure_at_zero():
    """At p <= 0 the bound is force_scale (Fs(0) + sigma2(0) |v|), not a line extrapolated below 0."""
    law = _law("maxwell-slip", (1.0, 1.0, 1.0, 1.0))
    t, tr = _truth(law)
    tr["p_cav_Pa"][10, 0] = -5e4     # within the pressure tolerance; the line there would give 1.24
    tr["friction_N"][10, 0] = 1.19 * (law.Fs.intercept + law.sigma2.intercept * abs(tr["piston_v_m_s"][10, 0]))
    check_truth(law, tr, t)


def test_a_negative_cavity_pressure_is_refused():
    law = _law("elasto-plastic")
    t, tr = _truth(law)
    tr["p_cav_Pa"][77, 1] = -20e6
    with pytest.raises(TruthError, match=r"rope 2: cavity pressure -20 MPa at t = 0\.385 s"):
        check_truth(law, tr, t)


def test_a_non_finite_truth_is_refused():
    law = _law("lugre")
    t, tr = _truth(law)
    tr["friction_N"][5, 0] = np.nan
    with pytest.raises(TruthError):
        check_truth(law, tr, t)


def test_a_truth_error_is_what_evaluate_and_the_cli_report():
    """`evaluate.simulate` turns FloatingPointError (and ScenarioError) into EvaluationError,
    `ropemon simulate` prints it and exits 1."""
    assert issubclass(TruthError, FloatingPointError)


def test_evaluate_refuses_a_runaway_truth(tmp_path, monkeypatch):
    """A run whose truth breaks the bounds never reaches truth.npz: evaluate.simulate raises."""
    from ropemon.lab import evaluate
    from ropemon.lab.plant import run

    real = run.check_truth

    def strict(law, truth, t, tol=run.FRICTION_TOL, p_tol_Pa=run.PRESSURE_TOL_PA):
        return real(law, truth, t, tol=0.05, p_tol_Pa=p_tol_Pa)   # every loaded seal "runs away"

    monkeypatch.setattr(run, "check_truth", strict)
    with pytest.raises(evaluate.EvaluationError, match=r"simulate short-test: rope \d: seal friction"):
        evaluate.simulate("short-test", tmp_path / "out", 1)
    assert not (tmp_path / "out" / "truth.npz").exists()
