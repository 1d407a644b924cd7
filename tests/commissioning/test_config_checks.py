"""`ropemon config` honours the fits' own checks: a compliance (or friction) fit whose check refused
it is refused unless told to use it anyway, a fit checked as marginal or unchecked, or carrying no
check at all, is warned of; a check that cannot be read is refused naming the field."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from ropemon.cli import main as ropemon

ROOT = Path(__file__).resolve().parents[2]
SCEN = ROOT / "scenarios"

# fit-compliance --site's check of the wind that refused a fit (figures of its worst rest)
WORSE = {"verdict": "worse", "tolerance_frac": 0.0031, "worst_harm_frac": 0.0197, "rests_found": 4,
         "rests": [], "not_compared": [], "motion_residual_rms_m": 1e-6, "motion_residual_frac": 0.02}
OK = dict(WORSE, verdict="ok", worst_harm_frac=-0.031)
FRICTION_OK = {"verdict": "ok", "data": "held-out levels", "noise_N": 65.0, "tolerance_N": 195.0,
               "worst": {"figures": "held_out", "part": "sliding", "harm_N": -4268.0}}


@pytest.fixture
def site_dir(tmp_path) -> Path:
    for name in ("paper-site.toml", "paper-friction.json", "paper-compliance.json"):
        shutil.copy(SCEN / name, tmp_path / name)
    fr = json.loads((tmp_path / "paper-friction.json").read_text())
    (tmp_path / "paper-friction.json").write_text(json.dumps(dict(fr, check=FRICTION_OK)))
    return tmp_path


def with_check(site_dir: Path, name: str, check, out: str) -> Path:
    doc = json.loads((site_dir / name).read_text())
    if check is None:
        doc.pop("check", None)
    else:
        doc["check"] = check
    (site_dir / out).write_text(json.dumps(doc))
    return site_dir / out


def config(site_dir: Path, *extra: str) -> int:
    return ropemon(["config", str(site_dir / "paper-site.toml"), "--out", str(site_dir / "node.json"), *extra])


def test_a_compliance_whose_check_refused_it_is_refused(site_dir, capsys):
    bad = with_check(site_dir, "paper-compliance.json", WORSE, "worse.json")
    assert config(site_dir, "--compliance", str(bad)) == 1
    err = capsys.readouterr().err
    assert not (site_dir / "node.json").exists()
    assert err.startswith("config: error: compliance.check.verdict: 'worse': the fit's own check found it makes "
                          "the node read worse than without it (the total at a rest of known load 1.97 % of the "
                          "load farther off than without it, tolerance 0.31 %); refused")
    assert "--accept-unchecked-compliance" in err and "(in " in err and "worse.json" in err
    # told to: used, with the warning
    assert config(site_dir, "--compliance", str(bad), "--accept-unchecked-compliance") == 0
    err = capsys.readouterr().err
    assert "config: warning: compliance.check.verdict: 'worse'" in err and "used anyway" in err
    assert json.loads((site_dir / "node.json").read_text())["physical"]["hydraulic_compliance_m_per_Pa"]


def test_the_sites_own_compliance_file_is_checked_too(site_dir, capsys):
    with_check(site_dir, "paper-compliance.json", WORSE, "paper-compliance.json")
    assert config(site_dir) == 1
    assert "compliance.check.verdict: 'worse'" in capsys.readouterr().err


def test_an_unchecked_compliance_is_warned_of(site_dir, capsys):
    """paper-compliance.json was fitted without --site: no check."""
    assert config(site_dir) == 0
    err = capsys.readouterr().err
    assert ("config: warning: compliance: the fit carries no check (fitted without --site): it was not compared "
            "with a known load") in err
    unchecked = with_check(site_dir, "paper-compliance.json", dict(OK, verdict="unchecked", worst_harm_frac=None),
                           "unchecked.json")
    assert config(site_dir, "--compliance", str(unchecked)) == 0
    assert "compliance: the fit's own check found no rest of known load" in capsys.readouterr().err
    marginal = with_check(site_dir, "paper-compliance.json", dict(OK, verdict="marginal", worst_harm_frac=0.002),
                          "marginal.json")
    assert config(site_dir, "--compliance", str(marginal)) == 0
    assert "compliance: the fit's own check found it no better than without it" in capsys.readouterr().err
    ok = with_check(site_dir, "paper-compliance.json", OK, "ok.json")
    assert config(site_dir, "--compliance", str(ok)) == 0
    err = capsys.readouterr().err
    assert "compliance:" not in err and "friction: the fit" not in err


@pytest.mark.parametrize("check,message", [
    ([], "compliance.check: must be an object, got list"),
    ({"verdict": "fine"}, "compliance.check.verdict: must be one of ok, marginal, unchecked, worse, got 'fine'"),
    (dict(OK, worst_harm_frac="large"), "compliance.check.worst_harm_frac: must be a number within -1..1"),
    (dict(OK, tolerance_frac=-0.1), "compliance.check.tolerance_frac: must be a number within 0..1"),
])
def test_a_check_that_cannot_be_read_is_refused_naming_the_field(site_dir, capsys, check, message):
    bad = with_check(site_dir, "paper-compliance.json", check, "bad.json")
    assert config(site_dir, "--compliance", str(bad)) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"config: error: {message}") and not (site_dir / "node.json").exists()


def test_a_friction_fit_whose_bed_check_refused_it_is_refused(site_dir, capsys):
    worse = dict(FRICTION_OK, verdict="worse", worst={"figures": "in_sample", "part": "sliding", "harm_N": 1776.0})
    bad = with_check(site_dir, "paper-friction.json", worse, "friction-worse.json")
    assert config(site_dir, "--friction", str(bad)) == 1
    err = capsys.readouterr().err
    assert err.startswith("config: error: friction.check.verdict: 'worse': the fit's own check found it makes the "
                          "node read worse than without it (1776 N rms more error on the bed's force than raw p x A, "
                          "tolerance 195 N); refused")
    assert "--accept-unchecked-friction" in err
    assert config(site_dir, "--friction", str(bad), "--accept-unchecked-friction") == 0
    assert "used anyway (--accept-unchecked-friction)" in capsys.readouterr().err
    old = with_check(site_dir, "paper-friction.json", None, "friction-old.json")
    assert config(site_dir, "--friction", str(old)) == 0
    assert "friction: the fit carries no check on the bed's force" in capsys.readouterr().err
    assert config(site_dir, "--friction", str(with_check(site_dir, "paper-friction.json",
                                                         dict(FRICTION_OK, verdict="unchecked"), "f.json"))) == 1
    assert "friction.check.verdict: must be one of ok, marginal, worse, got 'unchecked'" in capsys.readouterr().err
