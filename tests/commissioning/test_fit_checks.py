"""fit-compliance checks its own fit where the load is known: the node's float reference run over
the commissioning wind with the fit and without it, their totals at the rests of the empty cage
(SITE.toml's cage and tail ropes) or of a weighed payload compared, and a fit that puts the total
farther off than without it is refused with the figures; `--check` makes the same comparison on a
wind recorded in service. The wind is the lab simulator's (the paper's hoist and plant)."""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from ropemon.cli import main as ropemon
from ropemon.commission import compliance
from ropemon.commission.nodejson import seal
from ropemon.commission.reference import read_rsens
from ropemon.lab.plant.output import write_rsens

ROOT = Path(__file__).resolve().parents[2]
SCEN = ROOT / "scenarios"
START_M = 300.0      # the wind starts here (SITE.toml's start_depth_m) and ends at the pithead landing
PAYLOAD_KG = 6000.0
# what a compliance fit gives the physical section, and what only a config with one keeps
FIT_KEYS = ("hydraulic_compliance_m_per_Pa", "pressure_noise_Pa", "displacement_noise_m", "bounce_hz")
WITH_FIT_KEYS = ("friction_play_sigmas", "noise_follow_s")

WIND = f"""
name = "fit-check-wind"
rig = "hoist"
site = "site.toml"
seed = 3

[trip]
start_depth_m = {START_M}
v_max_m_s = 10.0
a_max_m_s2 = 0.8
jerk_m_s3 = 1.0

[[trip.phase]]
kind = "rest"
duration_s = 6.0
label = "bottom rest empty"

[[trip.phase]]
kind = "load"
payload_kg = {PAYLOAD_KG}
duration_s = 4.0
label = "loading"

[[trip.phase]]
kind = "rest"
duration_s = 6.0
label = "bottom rest loaded"

[[trip.phase]]
kind = "wind"
to_depth_m = 2.0
label = "wind up"

[[trip.phase]]
kind = "rest"
duration_s = 6.0
label = "pithead rest loaded"

[[trip.phase]]
kind = "load"
payload_kg = 0.0
duration_s = 4.0
label = "unloading"

[[trip.phase]]
kind = "rest"
duration_s = 6.0
label = "pithead rest empty"
"""


@pytest.fixture(scope="module")
def wind(tmp_path_factory) -> dict:
    """The simulated commissioning wind, its site, and node.json as `ropemon config` builds it
    before the compliance is fitted (no [compliance]): the simulator's with the fit's keys removed."""
    d = tmp_path_factory.mktemp("wind")
    for name in ("paper-friction.json", "paper-compliance.json"):
        shutil.copy(SCEN / name, d / name)
    site = (SCEN / "paper-site.toml").read_text()
    assert "start_depth_m = 808.0" in site
    (d / "site.toml").write_text(site.replace("start_depth_m = 808.0", f"start_depth_m = {START_M}"))
    plant = (SCEN / "short-test.toml").read_text()  # the field trip's hidden plant
    (d / "wind.toml").write_text(WIND + plant[plant.index("[plant]"):])
    assert ropemon(["simulate", str(d / "wind.toml"), "--out", str(d / "sim")]) == 0
    doc = json.loads((d / "sim" / "node.json").read_text())
    assert doc["physical"]["start_depth_m"] == START_M
    bare = {k: v for k, v in doc.items() if k not in ("physical", "sha256")}
    node = d / "node.json"
    ph = {k: v for k, v in doc["physical"].items() if k not in FIT_KEYS + WITH_FIT_KEYS}
    node.write_text(json.dumps(seal(dict(bare, physical=ph))))
    truth = json.loads((d / "sim" / "truth.json").read_text())
    return {"dir": d, "site": d / "site.toml", "node": node, "rsens": d / "sim" / "sensors.rsens",
            "physical": json.loads(node.read_text())["physical"], "bare": bare, "phases": truth["phases"]}


def air_like(w: dict, out: Path, c: float = 0.3) -> Path:
    """The wind's recording with its pistons moving as if the oil's compliance grew at low
    pressure (entrained air): k(p) = k (1 + c (1 - 2 (p - 6 MPa) / 6 MPa)) on top of the plant's
    compression (k = 3e-10 m/Pa), so that one straight k fitted over the whole wind is wrong for
    the unloading at the pithead."""
    ph = w["physical"]
    n, hz, rec = read_rsens(w["rsens"])
    rec = rec.copy()
    for i in range(n):
        p, x, _, _, _ = compliance._scaled(ph, rec, i)
        x = x + 3e-10 * c * ((p - 6e6) - (p - 6e6) ** 2 / 6e6)
        dc = ph["displacement_channels"][i]
        (lo, hi), c_lo, c_hi = dc["range_m"], dc["counts_lo"], dc["counts_hi"]
        rec[:, n + i] = np.clip(np.round(c_lo + (x - lo) * (c_hi - c_lo) / (hi - lo)), 0, 65535)
    write_rsens(out, rec, hz)
    return out


def fit_compliance(w: dict, *extra: str, rsens: Path | None = None, node: Path | None = None,
                   out: Path | None = None) -> int:
    args = ["fit-compliance", str(node or w["node"]), str(rsens or w["rsens"]), "--site", str(w["site"])]
    return ropemon(args + (["--out", str(out)] if out else []) + list(extra))


def figures(err: str) -> list[str]:
    return [line for line in err.splitlines()
            if line.startswith("ropemon fit-compliance: check: rest at") and "with the fit" in line]


def pct(text: str, name: str) -> float:
    """The % figure after `name` in a line of the check ("with the fit -2.82 % (-5.22 kN)")."""
    m = re.search(re.escape(name) + r" ([+-]\d+\.\d\d) % \(([+-]\d+\.\d\d) kN\)", text)
    assert m, (name, text)
    return float(m.group(1))


def test_rests_of_the_wind_are_found_at_their_depths(wind):
    """The standstills with the pressure steady, at the depths the node counts (start_depth_m and
    the shaft encoder): both landings, empty and loaded; the loading and unloading are not rests."""
    _, hz, rec = read_rsens(wind["rsens"])
    found = compliance.rests(wind["physical"], rec)
    rest_phases = [p for p in wind["phases"] if p["kind"] == "rest"]
    assert len(found) == len(rest_phases)
    for (a, b, depth), ph in zip(found, rest_phases):
        assert ph["t0_s"] <= a / hz < b / hz <= ph["t1_s"] + 0.01
        assert depth == pytest.approx(START_M if "bottom" in ph["label"] else 2.0, abs=0.5)


def test_a_fit_that_makes_the_rest_total_worse_is_refused_with_the_figures(wind, tmp_path, capsys):
    rsens = air_like(wind, tmp_path / "air.rsens")
    out = tmp_path / "compliance.json"
    assert fit_compliance(wind, rsens=rsens, out=out) == 2
    cap = capsys.readouterr()
    assert cap.out == "" and not out.exists()
    assert "error: the fitted compliance makes the node's total worse where the load is known" in cap.err
    # the figures: with the fit, without it, raw p x A, in % of the known load and kN
    msg = cap.err[cap.err.index("error: the fitted"):]
    # at the pithead after unloading: -2.8 % with the fit, -0.8 % without, raw p x A +8.9 %
    assert "(depth 1.9 m, empty cage 185.21 kN) it reads" in msg
    assert -3.2 < pct(msg, "it reads") < -2.4 and -1.1 < pct(msg, "with the fit,") < -0.5
    assert 8.5 < pct(msg, "raw p x A") < 9.3 and "without it (node.json as it is), raw p x A" in msg
    assert re.search(r": [12]\.\d\d % of the load farther off, beyond the tolerance 0\.3\d %; nothing written", msg)
    rows = figures(cap.err)
    assert len(rows) == 2  # the empty cage at the bottom before loading and at the pithead after unloading
    assert pct(rows[-1], "with the fit") == pct(msg, "it reads") and pct(rows[-1], "without") == pct(msg, "with the fit,")
    # the bottom rest before loading, where the node started at rest, reads well either way: the
    # worst rest decides
    assert abs(pct(rows[0], "with the fit")) < 0.2 and abs(pct(rows[0], "without")) < 0.3


def test_a_good_fit_is_accepted_and_its_check_recorded(wind, tmp_path, capsys):
    out = tmp_path / "compliance.json"
    assert fit_compliance(wind, out=out) == 0
    cap = capsys.readouterr()
    doc = json.loads(cap.out)
    assert json.loads(out.read_text()) == doc
    chk = doc["check"]
    assert chk["verdict"] == "ok" and chk["rests_found"] == 4 and len(chk["rests"]) == 2
    top = chk["rests"][-1]
    assert top["load"] == "empty cage" and top["known_N"] == pytest.approx(185.2e3, rel=1e-3)
    # at the pithead after unloading: with the fit within 0.1 %, without +3.1 %, raw +8.9 %
    assert abs(top["with_err"]) < 0.001 and 0.03 < top["without_err"] < 0.035 and 0.085 < top["raw_err"] < 0.095
    assert chk["worst_harm_frac"] < 0
    assert chk["motion_residual_frac"] < 0.1
    assert len(figures(cap.err)) == 2 and "error" not in cap.err and "warning" not in cap.err
    # the loaded rests: near no known load without --payload-kg, and said so
    assert len(chk["not_compared"]) == 2
    assert cap.err.count("load not known: reads") == 2 and cap.err.count("of a known load; not compared") == 2
    # a weighed payload makes the loaded rests known too
    assert fit_compliance(wind, "--payload-kg", str(PAYLOAD_KG)) == 0
    chk = json.loads(capsys.readouterr().out)["check"]
    assert [r["load"] for r in chk["rests"]] == ["empty cage", f"cage with {PAYLOAD_KG:g} kg",
                                                   f"cage with {PAYLOAD_KG:g} kg", "empty cage"]
    assert chk["verdict"] == "ok"


def test_the_check_in_service_reports_the_comparison(wind, tmp_path, capsys):
    """Against a node.json built with a compliance, the same comparison: this fit, the node as
    configured, and no compliance at all; --check exits 1 when the configured compliance reads
    the known load worse than none."""
    fit = compliance.fit(wind["physical"], read_rsens(wind["rsens"])[2]).as_dict()
    keys = {k: fit[k] for k in FIT_KEYS if fit.get(k) is not None}
    node = tmp_path / "node.json"
    node.write_text(json.dumps(seal(dict(wind["bare"], physical=dict(wind["physical"], **keys)))))
    assert fit_compliance(wind, "--check", node=node) == 0
    err = capsys.readouterr().err
    rows = figures(err)
    assert len(rows) == 2 and all("with no compliance" in r for r in rows)
    assert pct(rows[-1], "with the fit") == pct(rows[-1], "without")  # the same fit
    assert 2.8 < pct(rows[-1], "with no compliance") < 3.6 and "CHANGED" not in err
    # configured with half the oil's k (3e-10 m/Pa): that compliance reads the empty cage at the
    # pithead farther off than none (+6.0 % against +3.1 %), which --check names
    bad = dict(keys, hydraulic_compliance_m_per_Pa=[1.5e-10] * 4)
    node.write_text(json.dumps(seal(dict(wind["bare"], physical=dict(wind["physical"], **bad)))))
    assert fit_compliance(wind, "--check", node=node) == 1
    err = capsys.readouterr().err
    assert "its own compliance puts the total at the rest at" in err
    line = next(x for x in err.splitlines() if "its own compliance" in x)
    assert "farther off than no compliance" in line and line.endswith("CHANGED")


@pytest.mark.parametrize("extra,message", [
    (["--payload-kg", "0"], "--payload-kg: must be > 0 and at most 18000 kg"),
    (["--payload-kg", "20000"], "--payload-kg: must be > 0 and at most 18000 kg"),
    (["--payload-kg", "nan"], "--payload-kg: must be > 0"),
    ("other cage", "hoist.cage_mass_kg = 9000 kg weighs 88290 N, the node.json's physical.conveyance_weight_N"),
    ("no site", "--payload-kg: needs --site"),
    ("missing site", "site.toml: cannot read: No such file or directory"),
])
def test_a_known_load_that_cannot_be_used_is_refused(wind, tmp_path, capsys, extra, message):
    out = tmp_path / "compliance.json"
    if extra == "other cage":
        site = tmp_path / "site.toml"
        site.write_text(wind["site"].read_text().replace("cage_mass_kg = 8180.0", "cage_mass_kg = 9000.0"))
        shutil.copy(wind["dir"] / "paper-friction.json", tmp_path)
        shutil.copy(wind["dir"] / "paper-compliance.json", tmp_path)
        code = ropemon(["fit-compliance", str(wind["node"]), str(wind["rsens"]), "--site", str(site),
                        "--out", str(out)])
    elif extra == "missing site":
        code = ropemon(["fit-compliance", str(wind["node"]), str(wind["rsens"]), "--site", str(tmp_path / "site.toml"),
                        "--out", str(out)])
    elif extra == "no site":
        code = ropemon(["fit-compliance", str(wind["node"]), str(wind["rsens"]), "--payload-kg", "100",
                        "--out", str(out)])
    else:
        code = fit_compliance(wind, *extra, out=out)
    cap = capsys.readouterr()
    assert code == 2 and cap.out == "" and not out.exists()
    assert cap.err.startswith("ropemon fit-compliance: error: ") and message in cap.err


def fig(with_err: float, without_err: float, known: float = 185e3) -> compliance.RestFigure:
    return compliance.RestFigure(70.0, 2.0, "empty cage", known, known * (1 + with_err), known * (1 + without_err),
                                 known * 1.05)


@pytest.mark.parametrize("with_err,without_err,verdict", [
    (0.0005, 0.030, "ok"),        # better
    (0.0102, 0.010, "ok"),        # farther off by 0.02 %: within what the channels resolve
    (-0.012, 0.010, "marginal"),  # by 0.2 %: accepted with a warning
    (-0.014, 0.010, "worse"),     # by 0.4 %: refused
])
def test_the_verdict_and_its_tolerance(with_err, without_err, verdict):
    chk = compliance.FitCheck([fig(0.0, 0.05), fig(with_err, without_err)], 0.003, 1e-6, 0.02, 3)
    assert chk.verdict == verdict and chk.worst.harm == pytest.approx(abs(with_err) - abs(without_err))
    warned = compliance.check_warnings(chk)
    assert bool(warned) == (verdict == "marginal")
    if warned:
        assert warned[0].startswith("the fit puts the total at the rest at 70.0 s 0.20 % of the load farther off")


def test_no_rest_of_known_load_leaves_the_fit_unchecked_and_says_so():
    chk = compliance.FitCheck([], 0.003, 1e-6, 0.2, 2, [(5.0, 300.0, 210e3), (70.0, 2.0, 250e3)])
    assert chk.verdict == "unchecked" and chk.as_dict()["worst_harm_frac"] is None
    warned = compliance.check_warnings(chk)
    assert warned[0].startswith("the fit is not checked: none of the recording's 2 rests reads within 10 % of a known")
    assert "departs from what the fitted compliance predicts" in warned[1] and "20 % of the predicted" in warned[1]
