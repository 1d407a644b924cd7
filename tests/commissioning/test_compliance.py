"""fit-compliance: k and the pressure noise are recovered from a synthetic wind; a recording
without one, or where the position does not follow the pressure, is refused; SITE.toml's
[compliance] file reaches physical and the node section."""
from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from ropemon.commission import compliance
from ropemon.cli import main as ropemon
from ropemon.firmware import node_module
from ropemon.commission.nodejson import example_physical, make_node_json, seal
from ropemon.lab.plant.output import write_rsens
from ropemon.commission.site import SiteError, load_site, physical_from_site

ROOT = Path(__file__).resolve().parents[2]
SCEN = ROOT / "scenarios"
HZ = 200
K_TRUE = [2.0e-10, 3.0e-10, 3.5e-10, 5.0e-10]   # m/Pa: the paper hoist's cylinders are ~3e-10
X0 = [-0.010, 0.0, 0.004, 0.012]                 # m: piston positions at zero pressure
P_NOISE = 5e3                                    # Pa rms
X_NOISE = 2e-5                                   # m rms


def wind_pressure(seconds_scale: float = 1.0) -> np.ndarray:
    """Cavity pressure of a commissioning record (Pa): rest, loading ramp 4 -> 9 MPa,
    rest, a wind (acceleration hump, rope bounce, deceleration dip), rest."""
    def seg(p0, p1, s):
        return np.linspace(p0, p1, int(s * seconds_scale * HZ), endpoint=False)

    def hump(dp, s):
        return 9e6 + dp * np.sin(np.linspace(0, np.pi, int(s * HZ))) ** 2

    p = np.concatenate([seg(4e6, 4e6, 20), seg(4e6, 9e6, 15), seg(9e6, 9e6, 10), hump(0.8e6, 4),
                        seg(9e6, 9e6, 30), hump(-0.8e6, 4), seg(9e6, 9e6, 15)])
    t = np.arange(p.size) / HZ
    return p + 0.2e6 * np.sin(2 * np.pi * 1.5 * t) * ((t > 45) & (t < 100))  # rope bounce in the wind


def counts(value: np.ndarray, c_lo: int, c_hi: int, lo: float, hi: float) -> np.ndarray:
    return np.clip(np.round(c_lo + (value - lo) * (c_hi - c_lo) / (hi - lo)), 0, 65535)


def records(ph: dict, p: np.ndarray | list, x: np.ndarray | list) -> np.ndarray:
    """The .rsens records of per-rope pressures p[i] (Pa) and positions x[i] (m), on ph's channels."""
    n = ph["ropes"]
    rec = np.zeros((len(p[0]), 2 * n + 4), dtype=np.uint16)
    for i in range(n):
        pc, dc = ph["pressure_channels"][i], ph["displacement_channels"][i]
        rec[:, i] = counts(p[i], pc["counts_4mA"], pc["counts_20mA"], *pc["range_Pa"])
        rec[:, n + i] = counts(x[i], dc["counts_lo"], dc["counts_hi"], *dc["range_m"])
    rec[:, 2 * n] = 16000  # battery
    return rec


def synthetic(ph: dict, p_noise: float = P_NOISE, seed: int = 5, x_noise: float = X_NOISE) -> np.ndarray:
    """x = x0 + k p + noise on every rope, the transmitters' noise on p."""
    rng = np.random.default_rng(seed)
    p = wind_pressure()
    ps = [p + rng.normal(0, p_noise, p.size) for _ in K_TRUE]
    xs = [x0 + k * p + rng.normal(0, x_noise, p.size) for k, x0 in zip(K_TRUE, X0)]
    return records(ph, ps, xs)


@pytest.fixture(scope="module")
def ph() -> dict:
    return example_physical()


def test_k_is_recovered_within_1_percent(ph):
    res = compliance.fit(ph, synthetic(ph))
    for got, want in zip(res.k_m_per_pa, K_TRUE):
        assert got == pytest.approx(want, rel=0.01)
    assert min(res.r) > 0.99
    assert res.span_pa[0] == pytest.approx(5e6, rel=0.1)
    assert max(res.residual_m) < 2 * X_NOISE
    assert res.samples == wind_pressure().size


@pytest.mark.parametrize("noise", [2e3, 5e3, 20e3])
def test_pressure_noise_is_estimated_within_15_percent(ph, noise):
    # the ramp, the wind's humps and the rope bounce are signal, not noise
    res = compliance.fit(ph, synthetic(ph, p_noise=noise))
    pc = ph["pressure_channels"][0]
    step = (pc["range_Pa"][1] - pc["range_Pa"][0]) / (pc["counts_20mA"] - pc["counts_4mA"])
    want = np.hypot(noise, step / np.sqrt(12))  # the counts' quantisation is noise the node sees too
    assert res.pressure_noise_pa == pytest.approx(want, rel=0.15)


def test_the_pressure_noise_is_the_median_channels(ph):
    # one transmitter 40 % noisier than the other three does not size the node's observer:
    # its LuGre position follows the median pressure, its noise following the median
    # channel's level (docs/model.md), so the fit gives the median channel's noise
    rng = np.random.default_rng(3)
    p = wind_pressure()
    ps = [p + rng.normal(0, s, p.size) for s in (P_NOISE, P_NOISE, 1.4 * P_NOISE, P_NOISE)]
    xs = [x0 + k * p + rng.normal(0, X_NOISE, p.size) for k, x0 in zip(K_TRUE, X0)]
    res = compliance.fit(ph, records(ph, ps, xs))
    pc = ph["pressure_channels"][0]
    step = (pc["range_Pa"][1] - pc["range_Pa"][0]) / (pc["counts_20mA"] - pc["counts_4mA"])
    assert res.pressure_noise_pa == pytest.approx(np.hypot(P_NOISE, step / np.sqrt(12)), rel=0.1)


@pytest.mark.parametrize("noise", [1e-5, 2e-5, 4e-5])
def test_displacement_noise_is_estimated_within_15_percent(ph, noise):
    # the pistons' compression (k p: the ramp, the humps, the bounce) is signal, not noise
    res = compliance.fit(ph, synthetic(ph, x_noise=noise))
    dc = ph["displacement_channels"][0]
    step = abs(dc["range_m"][1] - dc["range_m"][0]) / abs(dc["counts_hi"] - dc["counts_lo"])
    want = np.hypot(noise, step / np.sqrt(12))
    assert res.displacement_noise_m == pytest.approx(want, rel=0.15)
    assert res.as_dict()["displacement_noise_m"] == res.displacement_noise_m


def test_a_recording_without_a_pressure_change_is_refused(ph):
    rng = np.random.default_rng(1)
    p = wind_pressure()
    flat = np.full(p.size, 6e6) + 0.02e6 * np.sin(np.arange(p.size) / HZ)  # rope 3: no loading seen
    ps = [p, p, flat, p]
    ps = [q + rng.normal(0, P_NOISE, q.size) for q in ps]
    xs = [x0 + k * q + rng.normal(0, X_NOISE, q.size) for k, x0, q in zip(K_TRUE, X0, ps)]
    with pytest.raises(compliance.ComplianceError,
                       match=r"^rope 3: the pressure changes by 0\.0\d\d MPa .*at least 0\.3 MPa"):
        compliance.fit(ph, records(ph, ps, xs))


def test_a_position_that_does_not_follow_pressure_is_refused(ph):
    rng = np.random.default_rng(2)
    p = wind_pressure()
    t = np.arange(p.size) / HZ
    wander = 0.002 * np.sin(2 * np.pi * t / 37.0)  # ropes equalising, unrelated to the pressure
    xs = [x0 + wander + rng.normal(0, X_NOISE, p.size) for x0 in X0]
    with pytest.raises(compliance.ComplianceError, match=r"^rope 1: position does not follow pressure"):
        compliance.fit(ph, records(ph, [p] * 4, xs))
    # a failed position channel leaves too few samples, and says so
    rec = synthetic(ph)
    rec[:, 4 + 1] = 0
    with pytest.raises(compliance.ComplianceError, match=r"^rope 2: fewer than 100 samples"):
        compliance.fit(ph, rec)


# ---------------------------------------------------------------- command


@pytest.fixture
def recorded(tmp_path, ph) -> tuple[Path, Path]:
    node = tmp_path / "node.json"
    node.write_text(json.dumps(make_node_json(ph)))
    rsens = tmp_path / "wind.rsens"
    write_rsens(rsens, synthetic(ph), HZ)
    return node, rsens


def test_command_prints_the_fit_as_json(recorded, tmp_path, capsys):
    node, rsens = recorded
    out = tmp_path / "compliance.json"
    assert ropemon(["fit-compliance", str(node), str(rsens), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    doc = json.loads(printed)
    assert json.loads(out.read_text()) == doc
    assert set(doc) >= {"hydraulic_compliance_m_per_Pa", "pressure_noise_Pa", "r", "pressure_span_Pa"}
    for got, want in zip(doc["hydraulic_compliance_m_per_Pa"], K_TRUE):
        assert got == pytest.approx(want, rel=0.01)


def test_command_help(capsys):
    with pytest.raises(SystemExit) as e:
        ropemon(["fit-compliance", "--help"])
    assert e.value.code == 0
    assert "NODE.json SENSORS.rsens" in capsys.readouterr().out


@pytest.mark.parametrize("case,message", [
    ("junk rsens", "too short for a .rsens header"),
    ("not rsens", "not a version-1 .rsens stream"),
    ("missing rsens", "No such file"),
    ("no physical", "no physical section"),
    ("node not json", "not valid JSON"),
    ("other ropes", "4 ropes at 200 Hz"),
    ("flat wind", "rope 1: the pressure changes by"),
])
def test_command_refuses_a_bad_file_with_exit_2(recorded, tmp_path, capsys, ph, case, message):
    node, rsens = recorded
    if case == "junk rsens":
        rsens.write_bytes(b"RSNS")
    elif case == "not rsens":
        rsens.write_bytes(b"\0" * 100)
    elif case == "missing rsens":
        rsens.unlink()
    elif case == "no physical":
        node.write_text(json.dumps({"schema": 1, "node": {}}))
    elif case == "node not json":
        node.write_text("{physical")
    elif case == "other ropes":
        node.write_text(json.dumps(seal({"physical": dict(ph, ropes=3)})))
    elif case == "flat wind":
        n = np.full(2000, 6e6)
        write_rsens(rsens, records(ph, [n] * 4, [n * 3e-10] * 4), HZ)
    out = tmp_path / "compliance.json"
    assert ropemon(["fit-compliance", str(node), str(rsens), "--out", str(out)]) == 2
    cap = capsys.readouterr()
    assert cap.out == "" and not out.exists()
    assert cap.err.startswith("ropemon fit-compliance: error: ") and message in cap.err


def test_a_refit_against_a_commissioned_config_names_what_moved(recorded, tmp_path, capsys, ph):
    node, rsens = recorded
    fit = compliance.fit(ph, synthetic(ph))

    def run(**took) -> tuple[int, int, str]:
        node.write_text(json.dumps(seal({"physical": dict(ph, **took)})))
        out = tmp_path / "compliance.json"
        out.unlink(missing_ok=True)
        codes = [ropemon(["fit-compliance", str(node), str(rsens), "--out", str(out)] + check)
                 for check in ([], ["--check"])]
        cap = capsys.readouterr()
        assert json.loads(out.read_text()) == fit.as_dict()  # the fit is written either way
        return codes[0], codes[1], cap.err

    # built without a compliance: nothing to re-check; without --site the fit is not checked
    # against a known load (tests/commissioning/test_fit_checks.py), and says so
    plain, checked, err = run()
    assert (plain, checked) == (0, 0)
    assert err.splitlines() == ["ropemon fit-compliance: warning: the fit is not checked against a known load "
                                "(give --site SITE.toml: the node's total at the recording's rests with and "
                                "without it)"] * 2
    # built with this very fit: every value within its tolerance
    same = dict(hydraulic_compliance_m_per_Pa=fit.k_m_per_pa, pressure_noise_Pa=fit.pressure_noise_pa,
                bounce_hz=2.59)
    plain, checked, err = run(**same)
    assert (plain, checked) == (0, 0)
    assert "k +0.0 % on rope" in err and "pressure noise +0.0 %" in err
    assert "bounce not measured in this recording (was 2.59 Hz)" in err  # the synthetic wind has no stop
    assert "CHANGED" not in err and "no longer fits" not in err
    # the transmitters 30 % noisier than commissioned, and rope 3's k 2 % higher
    k = list(fit.k_m_per_pa)
    k[2] /= 1.02
    plain, checked, err = run(**dict(same, pressure_noise_Pa=fit.pressure_noise_pa / 1.3,
                                     hydraulic_compliance_m_per_Pa=k))
    assert (plain, checked) == (0, 1)
    assert "pressure noise +30.0 %" in err and "tolerance 25 %; the node follows it): CHANGED" in err
    assert "k +2.0 % on rope 3, the farthest" in err and "tolerance 1 %): CHANGED" in err
    assert "node.json no longer fits this hoist" in err
    # within tolerance: 10 % noisier, which the node's noise following takes up
    plain, checked, err = run(**dict(same, pressure_noise_Pa=fit.pressure_noise_pa / 1.1))
    assert (plain, checked) == (0, 0) and "pressure noise +10.0 %" in err and "CHANGED" not in err
    # with the plays fixed (noise_follow_s 0), 10 % is beyond the tolerance and 2 % within
    fixed = dict(same, noise_follow_s=0.0)
    plain, checked, err = run(**dict(fixed, pressure_noise_Pa=fit.pressure_noise_pa / 1.1))
    assert (plain, checked) == (0, 1)
    assert "pressure noise +10.0 %" in err and "tolerance 3 %, the node's plays fixed): CHANGED" in err
    plain, checked, err = run(**dict(fixed, pressure_noise_Pa=fit.pressure_noise_pa / 1.02))
    assert (plain, checked) == (0, 0) and "pressure noise +2.0 %" in err and "CHANGED" not in err


def test_recheck_of_the_bounce():
    fit = compliance.ComplianceFit(k_m_per_pa=[3e-10] * 4, r=[1.0] * 4, span_pa=[1e6] * 4, residual_m=[0.0] * 4,
                                   pressure_noise_pa=5000.0, displacement_noise_m=2e-5, samples=1000, bounce_hz=2.75)
    ph = {"hydraulic_compliance_m_per_Pa": [3e-10] * 4, "pressure_noise_Pa": 5000.0}
    assert [line for line, _ in compliance.recheck(ph, fit)] == [
        "k +0.0 % on rope 1, the farthest (3e-10 m/Pa, was 3e-10; tolerance 1 %)",
        "pressure noise +0.0 % (5000 Pa, was 5000; tolerance 3 %, the node's plays fixed)"]  # no bounce: none compared
    assert compliance.recheck(dict(ph, bounce_hz=2.59), fit)[-1] == (
        "bounce +0.16 Hz (2.75 Hz, was 2.59; tolerance 0.1 Hz)", True)
    assert compliance.recheck(dict(ph, bounce_hz=2.70), fit)[-1][1] is False
    assert compliance.recheck({"hydraulic_compliance_m_per_Pa": [3e-10] * 3}, fit) == []  # another hoist
    # the observer's flag: a line only where this wind's pistons say otherwise than the config
    assert not any("seal observer" in line for line, _ in compliance.recheck(ph, fit))
    off = dict(ph, observer_compliance=False)
    assert (f"the pistons kept their lines over 100 % of this wind (needs 90 %): the seal observer now takes k, "
            "node.json's does not take it; rebuild the config from this fit", True) in compliance.recheck(off, fit)
    lost = dataclasses.replace(fit, used_fraction=0.3)
    assert ("the pistons kept their lines over 30 % of this wind (needs 90 %): the seal observer now runs without "
            "k, node.json's takes it; rebuild the config from this fit", True) in compliance.recheck(ph, lost)
    assert not any("seal observer" in line for line, _ in compliance.recheck(off, lost))


# ---------------------------------------------------------------- SITE.toml [compliance]

FIT = {"hydraulic_compliance_m_per_Pa": [3.0e-10, 3.1e-10, 2.9e-10, 3.0e-10], "pressure_noise_Pa": 5200.0,
       "displacement_noise_m": 2.1e-5, "r": [0.997] * 4, "samples": 25688}


@pytest.fixture
def site_dir(tmp_path) -> Path:
    """The example site without its [compliance] table (the tests add their own)."""
    for name in ("paper-site.toml", "paper-friction.json"):
        shutil.copy(SCEN / name, tmp_path / name)
    site = tmp_path / "paper-site.toml"
    text = site.read_text()
    shipped = '[compliance]\nfile = "paper-compliance.json"'
    assert shipped in text
    site.write_text(text.replace(shipped, ""))
    return tmp_path


def test_shipped_site_has_a_measured_compliance():
    ph = physical_from_site(load_site(SCEN / "paper-site.toml"))
    assert all(2.9e-10 < k < 3.1e-10 for k in ph["hydraulic_compliance_m_per_Pa"])
    assert 4e3 < ph["pressure_noise_Pa"] < 7e3
    assert 2e-5 < ph["displacement_noise_m"] < 3e-5  # 20 um of transmitter noise and the ADC's


def with_compliance(site_dir: Path, fit=FIT, table: str = 'file = "compliance.json"') -> Path:
    site = site_dir / "paper-site.toml"
    site.write_text(site.read_text() + f"\n[compliance]\n{table}\n")
    if fit is not None:
        (site_dir / "compliance.json").write_text(json.dumps(fit))
    return site


def test_site_compliance_file_gives_the_physical_keys(site_dir):
    site = load_site(with_compliance(site_dir))
    assert site.compliance_path == site_dir / "compliance.json"
    ph = physical_from_site(site)
    assert ph["hydraulic_compliance_m_per_Pa"] == FIT["hydraulic_compliance_m_per_Pa"]
    assert ph["pressure_noise_Pa"] == FIT["pressure_noise_Pa"]
    assert ph["displacement_noise_m"] == FIT["displacement_noise_m"]
    assert "r" not in ph and "samples" not in ph
    # a fit made before the displacement noise was measured leaves the node's default
    older = {k: v for k, v in FIT.items() if k != "displacement_noise_m"}
    assert "displacement_noise_m" not in physical_from_site(site, compliance=older)
    # a fit given to physical_from_site overrides the file
    other = dict(FIT, hydraulic_compliance_m_per_Pa=[4e-10] * 4, pressure_noise_Pa=3e3)
    ph = physical_from_site(site, compliance=other)
    assert (ph["hydraulic_compliance_m_per_Pa"], ph["pressure_noise_Pa"]) == ([4e-10] * 4, 3e3)


def test_site_play_for_quieter_transmitters_reaches_the_node(site_dir, capsys):
    default = make_node_json(physical_from_site(load_site(with_compliance(site_dir))))
    site = site_dir / "paper-site.toml"
    site.write_text(site.read_text() + "friction_play_sigmas = 1.6\n")
    ph = physical_from_site(load_site(site))
    assert ph["friction_play_sigmas"] == 1.6
    wider = make_node_json(ph)
    play = [p * 1.6 / 1.45 for p in default["node"]["friction"]["play_q8um"]]
    assert wider["node"]["friction"]["play_q8um"] == pytest.approx(play, abs=2)  # steps of 0.01 um
    assert ropemon(["config", str(site), "--out", str(site_dir / "node.json")]) == 0
    assert "play 1.6 sigma (SITE.toml)" in capsys.readouterr().out
    text = site.read_text()
    for bad, message in (("1.1", "must be >= 1.2"), ("2.5", "must be <= 2"), ('"wide"', "must be a number")):
        site.write_text(text.replace("friction_play_sigmas = 1.6", f"friction_play_sigmas = {bad}"))
        with pytest.raises(SiteError, match=f"compliance.friction_play_sigmas: {message}"):
            load_site(site)


def test_site_noise_following_setting_reaches_the_node(site_dir, capsys):
    site = with_compliance(site_dir)
    assert make_node_json(physical_from_site(load_site(site)))["node"]["friction"]["noise_shift"] == 12  # 20 s
    text = site.read_text()
    site.write_text(text + "noise_follow_s = 0\n")
    ph = physical_from_site(load_site(site))
    assert ph["noise_follow_s"] == 0
    assert make_node_json(ph)["node"]["friction"]["noise_ref_q6"] == 0  # the plays stay as built
    assert ropemon(["config", str(site), "--out", str(site_dir / "node.json")]) == 0
    assert "noise following off (SITE.toml)" in capsys.readouterr().out
    site.write_text(text + "noise_follow_s = 80\n")
    assert make_node_json(physical_from_site(load_site(site)))["node"]["friction"]["noise_shift"] == 14
    for bad, message in (("2", "must be 0 \\(off\\) or at least 5 s"), ("900", "must be <= 600")):
        site.write_text(text + f"noise_follow_s = {bad}\n")
        with pytest.raises(SiteError, match=f"compliance.noise_follow_s: {message}"):
            load_site(site)


def test_site_without_compliance_leaves_the_keys_out(site_dir):
    site = load_site(site_dir / "paper-site.toml")
    assert site.compliance_path is None
    ph = physical_from_site(site)
    assert "hydraulic_compliance_m_per_Pa" not in ph and "pressure_noise_Pa" not in ph
    assert make_node_json(ph)["node"]["friction"]["compliance_q"] == [0, 0, 0, 0]
    # ... unless a fit is given
    ph = physical_from_site(site, compliance=FIT)
    assert ph["hydraulic_compliance_m_per_Pa"] == FIT["hydraulic_compliance_m_per_Pa"]


@pytest.mark.parametrize("edit,message", [
    ({"hydraulic_compliance_m_per_Pa": [3e-10] * 3},
     r"compliance \(compliance.json\).hydraulic_compliance_m_per_Pa: must have one entry per rope \(4\), got 3"),
    ({"hydraulic_compliance_m_per_Pa": [3e-10, 2e-6, 3e-10, 3e-10]},
     r"compliance \(compliance.json\).hydraulic_compliance_m_per_Pa\[1\]: must be <= 1e-06, got 2e-06"),
    ({"hydraulic_compliance_m_per_Pa": [3e-10, 3e-10, -1e-10, 3e-10]},
     r"hydraulic_compliance_m_per_Pa\[2\]: must be >= 0, got -1e-10"),
    ({"hydraulic_compliance_m_per_Pa": [3e-10, 3e-10, 3e-10, "3e-10"]},
     r"hydraulic_compliance_m_per_Pa\[3\]: must be a number, got '3e-10'"),
    ({"hydraulic_compliance_m_per_Pa": 3e-10}, r"hydraulic_compliance_m_per_Pa: missing or not a list"),
    ({"pressure_noise_Pa": 0.0}, r"compliance \(compliance.json\).pressure_noise_Pa: must be > 0, got 0"),
    ({"pressure_noise_Pa": None}, r"pressure_noise_Pa: must be a number, got None"),
    ({"displacement_noise_m": 0}, r"compliance \(compliance.json\).displacement_noise_m: must be > 0, got 0"),
    ({"displacement_noise_m": 0.002}, r"displacement_noise_m: must be <= 0.001, got 0.002"),
    ({"displacement_noise_m": "2e-5"}, r"displacement_noise_m: must be a number, got '2e-5'"),
])
def test_bad_compliance_file_is_refused_naming_the_field(site_dir, edit, message):
    site = load_site(with_compliance(site_dir, dict(FIT, **edit)))
    with pytest.raises(SiteError, match=message):
        physical_from_site(site)


@pytest.mark.parametrize("fit,table,message", [
    (None, 'file = "compliance.json"', r"^compliance.file: cannot read .*compliance.json"),
    ("[1, 2", 'file = "compliance.json"', r"^compliance.file: .*compliance.json is not valid JSON"),
    ([1, 2], 'file = "compliance.json"', r"^compliance \(compliance.json\): must be an object, got list"),
    (FIT, 'path = "compliance.json"', r"^compliance.file: missing"),
    (FIT, 'file = "compliance.json"\nk = 1', r"^compliance.k: unknown field"),
])
def test_unusable_compliance_table_or_file_is_refused(site_dir, fit, table, message):
    site = with_compliance(site_dir, None, table)
    if isinstance(fit, str):
        (site_dir / "compliance.json").write_text(fit)
    elif fit is not None:
        (site_dir / "compliance.json").write_text(json.dumps(fit))
    with pytest.raises(SiteError, match=message):
        physical_from_site(load_site(site))


def test_config_puts_the_compliance_in_the_node_section(site_dir, capsys):
    out = site_dir / "node.json"
    assert ropemon(["config", str(with_compliance(site_dir)), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    ph, fr = doc["physical"], doc["node"]["friction"]
    assert ph["hydraulic_compliance_m_per_Pa"] == FIT["hydraulic_compliance_m_per_Pa"]
    q, sh = fr["compliance_q"], fr["compliance_shift"]
    assert all(q) and len(q) == 4
    # (um/256 per kPa) * 2**shift
    for qi, k in zip(q, FIT["hydraulic_compliance_m_per_Pa"]):
        assert qi / (1 << sh) == pytest.approx(k * 1e3 * 256e6, rel=1e-3)
    assert fr["warmup_samples"] == 400  # 2 s at 200 Hz: the compliance defaults
    assert node_module("config").parse(doc).ropes == 4
    assert ("hydraulic compliance 300, 310, 290, 300 um/MPa per rope, pressure noise 5.2 kPa rms, "
            "displacement noise 21.0 um rms") in capsys.readouterr().out
    # the node sizes its stroke threshold from the fit's displacement noise, not the 20 um default
    assert ph["displacement_noise_m"] == FIT["displacement_noise_m"]
    default = make_node_json({k: v for k, v in ph.items() if k != "displacement_noise_m"})
    assert fr["stroke_q8um"] > default["node"]["friction"]["stroke_q8um"]
    # --compliance overrides the site's file; a bad one is refused, nothing written
    (site_dir / "other.json").write_text(json.dumps(dict(FIT, pressure_noise_Pa=-1)))
    out.unlink()
    assert ropemon(["config", str(site_dir / "paper-site.toml"), "--out", str(out),
                    "--compliance", str(site_dir / "other.json")]) == 1
    assert not out.exists()
    assert "config: error: compliance.pressure_noise_Pa: must be > 0, got -1" in capsys.readouterr().err


def test_config_keeps_a_fit_the_observer_does_not_take_for_the_oil_balance(site_dir, capsys):
    out = site_dir / "node.json"
    assert ropemon(["config", str(with_compliance(site_dir, dict(FIT, observer_compliance=False))),
                    "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["physical"]["observer_compliance"] is False
    assert doc["physical"]["hydraulic_compliance_m_per_Pa"] == FIT["hydraulic_compliance_m_per_Pa"]
    assert doc["node"]["friction"]["compliance_q"] == [0, 0, 0, 0]
    assert doc["node"]["friction"]["warmup_samples"] != 400   # not the compliance defaults
    assert node_module("config").parse(doc).ropes == 4
    assert "for the oil balance only: the seal observer runs without it" in capsys.readouterr().out


def test_uncertain_k_is_refused(ph):
    """A pressure change just above the minimum, under a noisy position, over a short
    recording: k would be uncertain by several per cent on every rope, and so would the
    common compliance of the pistons' summed volume, so it is refused, naming both."""
    rng = np.random.default_rng(9)
    p = np.concatenate([np.full(200, 4e6), np.linspace(4e6, 4.4e6, 200), np.full(200, 4.4e6)])
    ps = [p + rng.normal(0, P_NOISE, p.size) for _ in K_TRUE]
    xs = [x0 + k * p + rng.normal(0, 1e-4, p.size) for k, x0 in zip(K_TRUE, X0)]
    with pytest.raises(compliance.ComplianceError, match=r"rope 1: k = .* uncertain by .* %.*nor can the "
                       r"common compliance be measured: K = .* uncertain by [2-9]\.\d %"):
        compliance.fit(ph, records(ph, ps, xs))


def arrival(ph: dict, bounce_hz: float | None, amp_pa: float = 20e3, seed: int = 9,
            stop_s: float = 12.0, moving: bool = True) -> np.ndarray:
    """A wind's end: the hoist runs at 5 m/s (counter pulses), stops at `stop_s`, and the
    cage bounces at `bounce_hz` (decaying, 3 s) on 9 MPa, with 5 kPa of transmitter noise."""
    rng = np.random.default_rng(seed)
    n_s = int(20 * HZ)
    t = np.arange(n_s) / HZ
    p = 9e6 + np.zeros(n_s)
    if bounce_hz is not None:
        after = t >= stop_s
        p[after] += amp_pa * np.exp(-(t[after] - stop_s) / 3) * np.sin(2 * np.pi * bounce_hz * (t[after] - stop_s))
    ps = [p + rng.normal(0, P_NOISE, n_s) for _ in K_TRUE]
    xs = [x0 + k * p for k, x0 in zip(K_TRUE, X0)]
    rec = records(ph, ps, xs)
    if moving:  # 5 m/s of 10 mm pulses: 2.5 per sample, on a counter that wraps at 2**16
        pulses = np.floor(np.minimum(t, stop_s) * 5.0 / ph["speed_m_per_pulse"]).astype(np.int64)
        rec[:, 2 * ph["ropes"] + 2] = (pulses + 60000) % 65536
    return rec


@pytest.mark.parametrize("f", [1.6, 2.3, 2.8, 4.5])
def test_the_bounce_after_the_arrival_is_measured(ph, f):
    assert compliance.bounce_hz(ph, arrival(ph, f)) == pytest.approx(f, abs=0.03)


def test_no_bounce_is_reported_without_a_stop_or_a_line_above_the_noise(ph):
    assert compliance.bounce_hz(ph, arrival(ph, 2.3, moving=False)) is None    # the hoist never ran
    assert compliance.bounce_hz(ph, arrival(ph, 2.3, stop_s=17.0)) is None     # under 4 s after the stop
    assert compliance.bounce_hz(ph, arrival(ph, None)) is None                 # noise alone
    assert compliance.bounce_hz(ph, arrival(ph, 2.3, amp_pa=300.0)) is None     # buried in the noise
    # a fit's output carries it (None when not measured), and `ropemon config` takes it
    res = compliance.fit(ph, synthetic(ph))
    assert res.bounce_hz is None and res.as_dict()["bounce_hz"] is None


# ---------------------------------------------------------------- a wind with balancing strokes

AREAS = [1.0, 1.0, 1.0, 1.0]  # equal cylinders (the example site's)


def stroke_wind(ph: dict, seed: int = 4, strokes: bool = True, bounce: float = 2.4,
                loading: bool = True) -> np.ndarray:
    """A full commissioning wind as a sensor stream: loading at the bottom (5 -> 9 MPa), the
    wind up (acceleration hump, the tail-rope shift, deceleration dip, rope bounce), the stop
    at the pithead with the cage's bounce at `bounce` Hz, unloading (9 -> 4 MPa), rest.

    With `strokes` the shared manifold's balancing strokes: rope 2 takes all of the common
    motion through the deceleration and rope 4 all of the unloading's (the others stick;
    sum A_i x_i keeps following sum A_i k_i p_i), and rope 3 creeps 3 mm out through the
    wind while ropes 1, 2, 4 give 1 mm each back. Without `loading` the cage stays empty
    (9 MPa at rest at both ends): the pressure changes only in the wind."""
    rng = np.random.default_rng(seed)

    def seg(p0, p1, s):
        return np.linspace(p0, p1, int(s * HZ), endpoint=False)

    lo = 5e6 if loading else 9e6
    parts = [seg(lo, lo, 10), seg(lo, 9e6, 20), seg(9e6, 9e6, 6),        # rest, loading, rest
             seg(9e6, 9.6e6, 5), seg(9.6e6, 9.0e6, 8),                    # acceleration
             seg(9.0e6, 8.6e6, 60),                                       # full speed (tail ropes shift)
             seg(8.6e6, 8.0e6, 8), seg(8.0e6, 8.6e6, 5),                  # deceleration
             seg(8.6e6, 8.6e6, 12), seg(8.6e6, 4.0e6 if loading else 8.6e6, 15),  # pithead, unloading
             seg(4e6 if loading else 8.6e6, 4e6 if loading else 8.6e6, 10)]
    p = np.concatenate(parts)
    t = np.arange(p.size) / HZ
    edges = np.cumsum([0] + [q.size for q in parts]) / HZ
    t_go, t_stop = edges[3], edges[8]
    moving = (t >= t_go) & (t < t_stop)
    p = p + 0.15e6 * np.sin(2 * np.pi * 1.1 * t) * moving                  # the rope bounce in the wind
    after = t >= t_stop
    p[after] += 0.12e6 * np.exp(-(t[after] - t_stop) / 2.5) * np.sin(2 * np.pi * bounce * (t[after] - t_stop))
    k = np.array(K_TRUE)
    a = np.array(AREAS)
    x = X0 + np.outer(p, k)                                                # the oil's compression
    if strokes:
        for j, (t0, t1) in ((1, (edges[5] + 30, edges[8])), (3, (edges[9] + 2, edges[10]))):
            inside = (t >= t0) & (t < t1)
            i0 = np.argmax(inside)
            i1 = np.flatnonzero(inside)[-1]
            dp = np.zeros(p.size)
            dp[inside] = p[inside] - p[i0]
            dp[i1 + 1:] = p[i1] - p[i0]
            for i in range(4):  # the others stick, rope j takes their motion
                if i != j:
                    x[:, i] -= k[i] * dp
                    x[:, j] += a[i] * k[i] * dp / a[j]
        creep = np.clip((t - t_go) / (t_stop - t_go), 0, 1) * 3e-3
        x += np.outer(creep, [-1 / 3, -1 / 3, 1.0, -1 / 3]) * a[2] / a
    ps = [p + rng.normal(0, P_NOISE, p.size) for _ in K_TRUE]
    xs = [x[:, i] + rng.normal(0, X_NOISE, p.size) for i in range(4)]
    rec = records(ph, ps, xs)
    speed = np.interp(t, [t_go, t_go + 12, t_stop - 12, t_stop], [0, 10.0, 10.0, 0], left=0, right=0)
    depth = 808.0 - np.cumsum(speed) / HZ                                  # up the shaft: counts down
    rec[:, 2 * ph["ropes"] + 2] = np.floor((depth - 808.0) / ph["speed_m_per_pulse"]).astype(np.int64) % 65536
    return rec


def scaled(ph: dict, rec: np.ndarray, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Rope i's pressure (Pa) and position (m) from the records' counts."""
    pc, dc, n = ph["pressure_channels"][i], ph["displacement_channels"][i], ph["ropes"]
    (plo, phi), (xlo, xhi) = pc["range_Pa"], dc["range_m"]
    p = plo + (rec[:, i] - pc["counts_4mA"]) * (phi - plo) / (pc["counts_20mA"] - pc["counts_4mA"])
    x = xlo + (rec[:, n + i] - dc["counts_lo"]) * (xhi - xlo) / (dc["counts_hi"] - dc["counts_lo"])
    return p, x


def test_fit_compliance_accepts_a_wind_with_strokes(ph):
    """Balancing strokes and a creep put the pistons off a line of position on pressure
    over the whole wind; k comes from the rest of it, and the pithead bounce is measured."""
    rec = stroke_wind(ph)
    # the whole wind's line of position on pressure is broken on every rope
    for i, want in enumerate(K_TRUE):
        p, x = scaled(ph, rec, i)
        assert abs(np.polyfit(p, x, 1)[0] / want - 1) > 0.1
    res = compliance.fit(ph, rec)
    for got, want in zip(res.k_m_per_pa, K_TRUE):
        assert got == pytest.approx(want, rel=0.02)
    assert res.bounce_hz == pytest.approx(2.4, abs=0.05)
    # the strokes and the creep were left out, and the fit says how much of the wind it used
    assert res.left_out_s > 5 and 0.2 < res.used_fraction < 0.97
    # the oil's volume is kept: sum A x follows sum A k p over the whole wind, strokes included
    assert res.volume_ratio == pytest.approx(1.0, abs=0.02)
    # off their lines over most of the wind: k is for the oil balance, not for the seal observer
    assert res.used_fraction < compliance.OBSERVER_MIN_USED and not res.observer
    assert res.as_dict()["observer_compliance"] is False
    assert len(res.warnings) == 1 and "the node's seal observer runs without k" in res.warnings[0]
    # the same wind without strokes: nothing left out beyond the noise's few false alarms
    clean = compliance.fit(ph, stroke_wind(ph, strokes=False))
    assert clean.used_fraction > 0.97 and clean.observer and clean.warnings == []
    assert clean.as_dict()["observer_compliance"] is True
    for got, want in zip(clean.k_m_per_pa, K_TRUE):
        assert got == pytest.approx(want, rel=0.01)


def test_a_fit_the_observer_does_not_take_reaches_the_oil_balance_only(ph):
    """observer_compliance false: the node's observer (its node section, the float reference's
    parameters) runs as without a compliance, while the station's oil balance keeps k."""
    from ropemon.commission.nodejson import physical_params
    from ropemon.commission.site import check_compliance
    from ropemon.station.nodefigures import NodeFigures, alarm_settings
    from ropemon.station.physical import Physical

    res = compliance.fit(ph, stroke_wind(ph))
    off = compliance.with_fit(ph, res)
    assert off["observer_compliance"] is False and off["hydraulic_compliance_m_per_Pa"] == res.k_m_per_pa
    on = dict(off, observer_compliance=True)
    none = compliance.with_fit(ph, None)
    assert not compliance.has_compliance(off) and compliance.has_compliance(on)
    node = {name: make_node_json(d)["node"] for name, d in (("off", off), ("on", on), ("none", none))}
    assert node["off"]["friction"]["compliance_q"] == [0] * 4 and any(node["on"]["friction"]["compliance_q"])
    # the observer's settings are those of a node without a compliance (no tracker, no rest hold)
    keys = ("tracker_b_shift", "tracker_k_q14", "rest_q16um", "alpha_z_q14", "warmup_samples")
    assert all(node["off"]["friction"][k] == node["none"]["friction"][k] for k in keys)
    assert any(node["on"]["friction"][k] != node["none"]["friction"][k] for k in keys)
    assert physical_params(Physical.from_dict(off))["compliance"] == [0.0] * 4
    # the oil balance still takes the oil's compression
    eq = alarm_settings(NodeFigures.from_physical(Physical.from_dict(off))).equalizer
    assert eq.compliance_m_per_pa == pytest.approx(res.k_m_per_pa)
    # a fit file's flag must be a boolean
    with pytest.raises(SiteError, match=r"fit\.observer_compliance: must be true or false, got 0"):
        check_compliance(dict(res.as_dict(), observer_compliance=0), 4, "fit")


def test_command_fits_a_wind_with_strokes(tmp_path, ph, capsys):
    node = tmp_path / "node.json"
    node.write_text(json.dumps(make_node_json(ph)))
    rsens = tmp_path / "wind.rsens"
    write_rsens(rsens, stroke_wind(ph), HZ)
    assert ropemon(["fit-compliance", str(node), str(rsens)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["hydraulic_compliance_m_per_Pa"] == pytest.approx(K_TRUE, rel=0.02)
    assert doc["left_out_s"] > 5 and doc["bounce_hz"] == pytest.approx(2.4, abs=0.05)


def test_a_volume_that_does_not_follow_the_compression_is_warned(ph):
    # oil leaving the circuit (a leak on rope 3's cylinder, 20 um/s through the wind):
    # the sum of the pistons' volumes drifts away from the compression, which is warned
    rec = stroke_wind(ph, strokes=False)
    t = np.arange(rec.shape[0]) / HZ
    _, x = scaled(ph, rec, 2)
    leak = -np.clip(t - 36, 0, None) * 2e-5
    dc = ph["displacement_channels"][2]
    rec[:, 4 + 2] = counts(x + leak, dc["counts_lo"], dc["counts_hi"], *dc["range_m"])
    res = compliance.fit(ph, rec)
    assert abs(res.volume_ratio - 1) > 0.03
    assert res.warnings and "oil leaves or enters the circuit" in res.warnings[0]


# ---------------------------------------------------------------- ropes that part through the wind

GROOVE_CREEP = [1.2e-5, -1.2e-5, 0.6e-5, -0.6e-5]  # m of piston per m of the wheel's travel: +-10 mm a wind
SLIP_LAG_M = (2e-4, 4e-4)  # a piston sticks until it lags its creep by this much
SLIP_M_S = 150e-6         # ... then slips at this speed


def parting_wind(ph: dict, seed: int = 6, pressure_scale: float = 1.0) -> tuple[np.ndarray, float]:
    """stroke_wind's wind of an empty cage (strokes, creep) whose ropes also part through the wind with the
    wheel's travel (groove creep: the grooves' diameters differ), by stick-slip: each piston
    sticks until it lags its creep by 0.2-0.4 mm, then slips at 150 um/s. The oil's volume is
    kept (sum A_i x_i only follows the compression). `pressure_scale` shrinks the pressure's
    swings about its mean. Returns the records and the truth's K = sum A_i k_i (m^3/Pa)."""
    rec = stroke_wind(ph, seed=seed, loading=False)
    n = ph["ropes"]
    rng = np.random.default_rng(seed)
    m = rec.shape[0]
    counter = rec[:, 2 * n + 2].astype(np.int64)
    travel = np.abs(np.concatenate([[0], np.cumsum((np.diff(counter) + 32768) % 65536 - 32768)])) \
        * ph["speed_m_per_pulse"]
    a = np.asarray(compliance._areas(ph, n))
    creep = np.zeros((m, n))
    for i, g in enumerate(GROOVE_CREEP):
        target, c, slipping, lim = g * travel, 0.0, False, rng.uniform(*SLIP_LAG_M)
        for j in range(m):
            lag = target[j] - c
            if not slipping and abs(lag) > lim:
                slipping, lim = True, rng.uniform(*SLIP_LAG_M)
            if slipping:
                c += np.sign(lag) * min(abs(lag), SLIP_M_S / HZ)
                slipping = abs(target[j] - c) > 1e-6
            creep[j, i] = c
    creep -= np.outer(creep @ a / a.sum(), np.ones(n))  # the oil's volume is kept
    for i in range(n):
        p, x = scaled(ph, rec, i)
        pc, dc = ph["pressure_channels"][i], ph["displacement_channels"][i]
        if pressure_scale != 1.0:
            mid = float(np.mean(p))
            x = x - K_TRUE[i] * (p - mid) * (1 - pressure_scale)
            p = mid + (p - mid) * pressure_scale
            rec[:, i] = counts(p, pc["counts_4mA"], pc["counts_20mA"], *pc["range_Pa"])
        rec[:, n + i] = counts(x + creep[:, i], dc["counts_lo"], dc["counts_hi"], *dc["range_m"])
    return rec, float(a @ np.array(K_TRUE))


def test_a_wind_whose_ropes_part_falls_back_to_the_common_compliance(ph):
    """Groove creep parts the ropes by stick-slip all through the wind, so no piece is long
    enough to give each rope's k to 2 %; the manifold's volume line is not moved by it (the
    differential motions cancel in sum A_i x_i), so fit-compliance gives the common
    compliance K split in equal volume shares, and says so."""
    rec, k_sum = parting_wind(ph)
    res = compliance.fit(ph, rec)
    a = np.asarray(compliance._areas(ph, 4))
    assert res.method == "common"
    assert float(a @ np.array(res.k_m_per_pa)) == pytest.approx(k_sum, rel=0.01)
    assert res.common_m3_per_pa == pytest.approx(k_sum, rel=0.01)
    assert res.k_m_per_pa == pytest.approx([k_sum / (4 * a[0])] * 4, rel=1e-9)  # equal volume shares
    assert res.warnings and res.warnings[0].startswith("per-rope k not measured: rope")
    assert "the ropes part through the wind" in res.warnings[0] and "K = sum A_i k_i" in res.warnings[0]
    assert res.bounce_hz == pytest.approx(2.4, abs=0.05)
    doc = res.as_dict()
    assert doc["method"] == "common" and doc["common_compliance_m3_per_Pa"] == pytest.approx(k_sum, rel=0.01)
    # the wind with strokes alone still gives each rope's own k
    per = compliance.fit(ph, stroke_wind(ph))
    assert per.method == "per-rope" and per.k_m_per_pa == pytest.approx(K_TRUE, rel=0.02)


def test_a_parting_wind_without_a_usable_pressure_change_is_refused(ph):
    rec, _ = parting_wind(ph, pressure_scale=0.05)
    with pytest.raises(compliance.ComplianceError, match=r"^rope 1: the pressure changes by 0\.\d+ MPa"):
        compliance.fit(ph, rec)


def test_recheck_of_a_common_fit_compares_the_common_compliance(ph):
    """A common fit's per-rope k are equal shares, not each rope's: the re-check compares K."""
    rec, k_sum = parting_wind(ph)
    res = compliance.fit(ph, rec)
    a = np.asarray(compliance._areas(ph, 4))
    was = dict(ph, hydraulic_compliance_m_per_Pa=list(np.array(K_TRUE) * 1.004))  # per rope, K 0.4 % up
    (line, beyond), = [x for x in compliance.recheck(was, res) if x[0].startswith("K ")]
    assert not beyond and "common compliance" in line
    was = dict(ph, hydraulic_compliance_m_per_Pa=list(np.array(res.k_m_per_pa) * 1.03))
    (line, beyond), = [x for x in compliance.recheck(was, res) if x[0].startswith("K ")]
    assert beyond and float(a @ np.array(res.k_m_per_pa)) == pytest.approx(k_sum, rel=0.01)
