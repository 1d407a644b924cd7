"""fit-friction's residual: the fitted LuGre re-run on the bed's own record. Small on a LuGre
bed (the node's own law), beyond the documented limits and flagged on a seal the node does not
assume; `ropemon config` carries it into node.json's physical section."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from ropemon.commission import calibrate
from ropemon.lab import testbed
from ropemon.cli import main as ropemon
from ropemon.lab.plant.friction import example_table

ROOT = Path(__file__).resolve().parents[2]
PRESSURES = (2.0, 5.0, 8.0, 11.0)


def fit_bed(tmp, data, capsys):
    testbed.write_csv(tmp / "bed.csv", data)
    assert ropemon(["fit-friction", str(tmp / "bed.csv"), "--out", str(tmp / "friction.json")]) == 0
    out = capsys.readouterr()
    return json.loads((tmp / "friction.json").read_text()), out.out, out.err


@pytest.fixture(scope="module")
def lugre_fit(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("lugre")
    testbed.write_csv(tmp / "bed.csv", testbed.run(testbed.PAPER_SEAL, pressures_MPa=PRESSURES, seed=7))
    rec = calibrate.read_csv(tmp / "bed.csv")
    doc, _levels, warnings = calibrate.fit(rec)
    (tmp / "friction.json").write_text(json.dumps(doc))
    return doc, warnings, tmp


def test_on_a_lugre_bed_the_residual_is_the_instruments_noise(lugre_fit):
    doc, warnings, _ = lugre_fit
    res = doc["residual"]
    assert [round(lv["pressure_MPa"]) for lv in res["levels"]] == [2, 5, 8, 11]
    for lv in res["levels"]:
        fs = testbed.line(testbed.PAPER_SEAL, "Fs", lv["pressure_MPa"])
        assert lv["Fs_N"] == pytest.approx(fs, rel=0.03)
        for part in ("sliding", "presliding"):
            c = lv[part]
            assert c["samples"] > 200
            # the bed's force sensor: 30 N + 0.5 % rms, so at least ~0.5 % and (LuGre) not much more
            assert 0.004 < c["rms_frac"] < 0.025, (lv["pressure_MPa"], part, c)
            assert c["rms_N"] == pytest.approx(c["rms_frac"] * lv["Fs_N"])
            assert c["rms_N"] <= c["max_N"]
    assert res["representable"] is True
    assert res["sliding_rms_frac"] < calibrate.RESIDUAL_MAX_SLIDING / 2
    assert res["presliding_rms_frac"] < calibrate.RESIDUAL_MAX_PRESLIDING / 4
    assert not [w for w in warnings if w.startswith("residual")]


def test_a_wrong_model_makes_a_large_residual(lugre_fit):
    """The same record against the fit with its pre-sliding stiffness a hundredth: the
    residual is computed from the record, not reported from the fit."""
    doc, _, tmp = lugre_fit
    rec = calibrate.read_csv(tmp / "bed.csv")
    soft = dict(doc, sigma0=doc["sigma0"] / 100, sigma1=doc["sigma1"] / 100)
    res = calibrate.residual(rec, soft)
    assert res["presliding_rms_frac"] > 3 * doc["residual"]["presliding_rms_frac"]


def seal_file(path: Path, table: dict) -> Path:
    """A scenario holding only [plant.friction] (all testbed.scenario_seal reads)."""
    rows = ["[plant.friction]"]
    for k, v in table.items():
        if isinstance(v, dict):
            rows.append(f"{k} = {{ intercept = {v['intercept']!r}, slope = {v['slope']!r} }}")
        else:
            rows.append(f"{k} = {json.dumps(v)}")
    path.write_text("\n".join(rows) + "\n")
    return path


def test_a_coulomb_stribeck_seal_is_flagged_sliding_and_presliding(tmp_path, capsys):
    # no pre-sliding state: the force follows the velocity and vanishes at rest
    table = example_table("coulomb-stribeck")
    table["v_threshold"] = 2e-5
    params, factory = testbed.scenario_seal(seal_file(tmp_path / "cs.toml", table))
    doc, out, err = fit_bed(tmp_path, testbed.run(params, law_factory=factory, pressures_MPa=PRESSURES,
                                                  seed=7), capsys)
    res = doc["residual"]
    assert res["representable"] is False
    assert res["sliding_rms_frac"] > 2 * calibrate.RESIDUAL_MAX_SLIDING
    assert res["presliding_rms_frac"] > 2 * calibrate.RESIDUAL_MAX_PRESLIDING
    assert "warning: residual: the fitted LuGre does not reproduce this seal's force" in err
    assert "BEYOND the limits" in out
    assert any(w.startswith("residual:") for w in doc["warnings"])


def test_an_elasto_plastic_seal_is_flagged_in_presliding(tmp_path, capsys, lugre_fit):
    """Its steady state is LuGre's (sliding fits within the limit), its pre-sliding is not:
    purely elastic up to 40 % of the break-away deflection, then a plastic blend."""
    params, factory = testbed.scenario_seal(seal_file(tmp_path / "ep.toml", example_table("elasto-plastic")))
    doc, out, err = fit_bed(tmp_path, testbed.run(params, law_factory=factory, pressures_MPa=PRESSURES,
                                                  seed=7, presliding_period_s=testbed.presliding_period_s(params)),
                            capsys)
    res = doc["residual"]
    assert res["sliding_rms_frac"] <= calibrate.RESIDUAL_MAX_SLIDING
    assert res["presliding_rms_frac"] > calibrate.RESIDUAL_MAX_PRESLIDING
    assert res["presliding_rms_frac"] > 4 * lugre_fit[0]["residual"]["presliding_rms_frac"]
    assert res["representable"] is False
    assert "pre-sliding RMS" in err and "limit 10 %" in err


def test_the_command_prints_the_table(lugre_fit, capsys):
    _, _, tmp = lugre_fit
    assert ropemon(["fit-friction", str(tmp / "bed.csv"), "--out", str(tmp / "again.json")]) == 0
    out = capsys.readouterr().out
    assert "residual of the fitted model on the record" in out and "within the limits (5 %, 10 %)" in out
    rows = [ln.split() for ln in out.splitlines() if ln.strip().startswith(("2.", "5.", "8.", "11."))]
    assert len(rows) == 4


def test_config_carries_the_residual_into_physical(lugre_fit, tmp_path, capsys):
    doc, _, tmp = lugre_fit
    site = tmp_path / "site.toml"
    text = (ROOT / "scenarios" / "paper-site.toml").read_text()
    text = text.replace('file = "paper-compliance.json"', f'file = "{ROOT / "scenarios" / "paper-compliance.json"}"')
    site.write_text(text.replace('file = "paper-friction.json"', f'file = "{tmp / "friction.json"}"'))
    assert ropemon(["config", str(site), "--out", str(tmp_path / "node.json")]) == 0, capsys.readouterr().err
    phys = json.loads((tmp_path / "node.json").read_text())["physical"]
    assert phys["friction_residual_frac"] == {"sliding": doc["residual"]["sliding_rms_frac"],
                                              "presliding": doc["residual"]["presliding_rms_frac"]}
    bad = dict(doc, residual={"sliding_rms_frac": "large", "presliding_rms_frac": 0.01})
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    assert ropemon(["config", str(site), "--friction", str(tmp_path / "bad.json"),
                    "--out", str(tmp_path / "n2.json")]) != 0
    assert "residual.sliding_rms_frac: must be a number" in capsys.readouterr().err
    old = {k: v for k, v in doc.items() if k != "residual"}
    (tmp_path / "old.json").write_text(json.dumps(old))
    assert ropemon(["config", str(site), "--friction", str(tmp_path / "old.json"),
                    "--out", str(tmp_path / "n3.json")]) == 0
    assert "friction_residual_frac" not in json.loads((tmp_path / "n3.json").read_text())["physical"]
