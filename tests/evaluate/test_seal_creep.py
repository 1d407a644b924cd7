"""tools/seal_creep.py: the pistons' creep and path against the node's over a window."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from ropemon.lab import evaluate as EV

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("seal_creep", ROOT / "tools" / "seal_creep.py")
sc = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(sc)


def test_change_is_the_difference_of_the_means_around_the_two_ends():
    # a ramp of 2 per sample in one column and a step in the other: the means over +-2
    # samples around 10 and 30 differ by 40 and by the step
    a = np.stack([2.0 * np.arange(50), np.where(np.arange(50) >= 20, 5.0, 1.0)], axis=1)
    assert np.allclose(sc._change(a, 10, 30, 2), [40.0, 4.0])


def test_on_the_short_wind(tmp_path, capsys):
    work = tmp_path / "short-test"
    EV.build_case("short-test", work, 1, firmware=False, bed=EV.BED_QUICK)
    truth = np.load(work / "sim" / "truth.npz")
    end_s = len(truth["piston_x_m"]) / 200
    t0, t1 = 1.0, end_s - 1.0
    rows = dict(sc.creep(work, t0, t1))
    assert len(rows) == 8
    x = truth["piston_x_m"]
    i0, i1 = 200, int(round(t1 * 200))
    # the true creep, read straight from the truth
    want = (x[i1 - 20:i1 + 20].mean(0) - x[i0 - 20:i0 + 20].mean(0)) * 1e6
    assert np.allclose(rows["creep, true piston (um)"], want)
    # the pistons move in this wind, and a path is at least the net travel
    assert np.all(np.abs(want) > 20)
    assert np.all(rows["path, true piston (um)"] >= np.abs(want) - 1e-9)
    # the node's LuGre position follows the piston (k p + b) within a few um
    assert np.all(np.abs(rows["creep, node's LuGre position (um)"] - want) < 3 + 0.05 * np.abs(want))
    # its dissipation path is its LuGre position through the play: shorter than
    # that position's own noisy path but at least its net travel less the play's width
    assert np.all(rows["path, node's dissipation (um)"] >= np.abs(rows["creep, node's LuGre position (um)"]) - 2)
    # while the cage moves the play loses little of the path (about 7 % on this wind)
    assert np.all(np.abs(rows["path, node's dissipation (um)"] / rows["path, true piston (um)"] - 1) < 0.15)
    # the plant's friction level at the window's end, read straight from the truth
    f = truth["friction_N"][i1 - 20:i1 + 20].mean(0) / 1e3
    assert np.allclose(rows[f"seal friction at {t1:g} s, plant (kN)"], f)
    assert sc.main([str(work), str(t0), str(t1)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert sum(line.startswith(("| creep", "| path", "| seal")) for line in out) == 8
    # a setting changed: the observer without its play (0 sigmas) takes the noise's whole
    # path as seal path, the truth stays as it is
    loose = dict(sc.creep(work, t0, t1, {"friction_play_sigmas": 0.0}))
    assert np.all(loose["path, node's dissipation (um)"] > rows["path, node's dissipation (um)"] + 10)
    assert np.array_equal(loose["path, true piston (um)"], rows["path, true piston (um)"])
    assert sc.main([str(work), str(t0), str(t1), "--set", "friction_play_sigmas=0"]) == 0
    assert "friction_play_sigmas=0" in capsys.readouterr().out.splitlines()[0]
    with pytest.raises(SystemExit):
        sc.main([str(work), str(t0), str(t1), "--set", "friction_play_sigmas"])
    assert "expected KEY=VALUE" in capsys.readouterr().err
    with pytest.raises(ValueError, match="must lie inside the run"):
        sc.creep(work, 1.0, end_s + 1.0)
