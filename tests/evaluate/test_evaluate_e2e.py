"""`ropemon evaluate` end to end on the short scenario: simulator, test bed and fit,
site config, float reference, firmware under micropython, metrics, report files."""
import json

import numpy as np
import pytest

from ropemon import cli
from ropemon.lab import estimators as E
from ropemon.lab import evaluate as ev


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("evaluate")
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = cli.main(["evaluate", "short-test", "--quick", "--json", "--out", str(out)])
    return rc, json.loads(buf.getvalue()), out


def test_json_has_every_estimator_with_the_agreed_keys(short_run):
    rc, doc, _ = short_run
    assert rc == 0
    sc = doc["scenarios"]["short-test"]
    assert "error" not in sc
    names = set(sc["estimators"])
    assert set(E.ESTIMATORS) | {"firmware"} == names
    for name, f in sc["estimators"].items():
        for key in ("rope_rms_pct", "rope_peak_pct", "pithead_total_pct"):
            assert isinstance(f[key], float), (name, key)
        assert f["rope_peak_pct"] >= f["rope_rms_pct"] >= 0
        assert set(f["by_phase"]) == set(ev.M.PHASES)
        assert set(f["alarms"]) == {"8", "10", "12"}


def test_raw_pithead_error_matches_the_truth_files(short_run):
    """The raw p*A error at the pithead rest, recomputed here from truth.npz alone."""
    _, doc, out = short_run
    truth = np.load(out / "runs" / "short-test" / "sim" / "truth.npz")
    meta = json.loads((out / "runs" / "short-test" / "sim" / "truth.json").read_text())
    area = np.asarray(meta["cylinder_area_m2"])
    t = truth["t_s"]
    speed = truth["wheel_speed_m_s"]
    still = (np.abs(speed) < 0.01) & (np.abs(truth["wheel_accel_m_s2"]) < 0.01)
    moved = np.flatnonzero(~still)
    # short-test creeps from 2 m to 5 m below the landing and rests there: that rest,
    # after the motion, is the pithead rest the figure is over (metrics.pithead_total_pct)
    assert moved.size and still[moved[-1] + 1:].sum() > 100
    rest = still & (np.arange(len(t)) > moved[0])
    raw_sum = (truth["p_tap_Pa"][rest] * area).sum(axis=1).mean()
    true_sum = truth["tension_N"][rest].sum(axis=1).mean()
    expect = (raw_sum - true_sum) / true_sum * 100
    got = doc["scenarios"]["short-test"]["estimators"]["raw"]["pithead_total_pct"]
    # the node reads p_tap through a noisy 16-bit transmitter channel: 0.05 % of a ~6 MPa reading
    assert got == pytest.approx(expect, abs=0.05)


def test_node_commissioned_from_its_own_fitted_seal(short_run):
    """The fitted sigma0 (not fit-friction's default) is in the config the firmware ran with."""
    _, doc, out = short_run
    c = doc["scenarios"]["short-test"]["commissioning"]
    assert c["ok"] and c["problems"] == []
    assert c["presliding_source"] in ev.SIGMA0_FITTED
    node = json.loads((out / "runs" / "short-test" / "node-evaluated.json").read_text())
    assert node["physical"]["friction"]["sigma0"] == pytest.approx(c["sigma0_N_per_m"])


def test_pithead_total_of_a_scenario_without_an_empty_cage_rest(short_run):
    """short-test ends loaded at the pithead: no empty-cage rest, so the total is the arrival one."""
    _, doc, _ = short_run
    for f in doc["scenarios"]["short-test"]["estimators"].values():
        assert f["pithead_empty_total_pct"] is None
        assert f["pithead_total_basis"] == "arrival"
        assert f["pithead_total_pct"] == f["pithead_arrival_total_pct"]


def test_firmware_agrees_with_the_float_reference(short_run):
    _, doc, _ = short_run
    fw = doc["scenarios"]["short-test"]["estimators"]["firmware"]
    assert fw["frames"] >= 60
    assert fw["vs_reference_max_pct"] <= ev.TARGETS["vs_reference_max_pct"]


def test_report_files_written(short_run):
    _, doc, out = short_run
    assert json.loads((out / "results.json").read_text())["scenarios"].keys() == doc["scenarios"].keys()
    md = (out / "accuracy.md").read_text()
    assert md.startswith("Made by `ropemon evaluate short-test --out")
    assert "| lugre-p+loss |" in md
    for png in ("short-test-tension.png", "rms-by-estimator.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"


def test_unknown_scenario_is_refused(capsys):
    assert cli.main(["evaluate", "no-such-scenario"]) == 2
    assert "no-such-scenario" in capsys.readouterr().err


def test_diagnostics_include_the_node_without_stroke_tracking(short_run):
    """The short wind has no balancing stroke: the node without stroke tracking reads
    within a few hundredths of a per cent of the node as commissioned."""
    _, doc, _ = short_run
    sc = doc["scenarios"]["short-test"]
    d = sc["diagnostics"][f"{E.FULL_COMPENSATION}, {ev.NO_STROKES_DIAGNOSTIC}"]
    assert abs(d["rope_rms_pct"] - sc["estimators"][E.FULL_COMPENSATION]["rope_rms_pct"]) < 0.05


def test_scenarios_run_in_parallel_give_the_serial_results_in_order(tmp_path):
    # two scenarios with one seal: the second process waits for the first's friction fit (its cache)
    src = ev.scenario_path("short-test")
    import shutil
    shutil.copytree(src.parent, tmp_path / "scenarios")     # with the site and compliance files it names
    twin = tmp_path / "scenarios" / "short-twin.toml"
    twin.write_text(src.read_text())
    names = [str(twin), "short-test"]
    par = ev.evaluate(names, tmp_path / "par", firmware=False, bed=ev.BED_QUICK, jobs=2)
    ser = ev.evaluate(names[:1], tmp_path / "ser", firmware=False, bed=ev.BED_QUICK, jobs=1)
    assert list(par["scenarios"]) == ["short-twin", "short-test"]
    fits = sorted(p.name for p in (tmp_path / "par").glob("friction-*.json"))
    assert len(fits) == 1, fits
    a, b, c = par["scenarios"]["short-twin"], par["scenarios"]["short-test"], ser["scenarios"]["short-twin"]
    for r in (a, b, c):
        assert "error" not in r, r.get("error")
    for name in E.ESTIMATORS:
        assert a["estimators"][name]["rope_rms_pct"] == b["estimators"][name]["rope_rms_pct"] \
            == c["estimators"][name]["rope_rms_pct"], name
