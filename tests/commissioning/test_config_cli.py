"""`ropemon config`: SITE.toml -> node.json that the node accepts; bad input refused, nothing written."""
from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import pytest

from ropemon.cli import main as ropemon
from ropemon.firmware import node_module
from ropemon.commission.nodejson import make_node_json
from ropemon.commission.site import load_site, physical_from_site

ROOT = Path(__file__).resolve().parents[2]
SCEN = ROOT / "scenarios"

# docs/config.md, "physical keys": the contract with the node and the float reference
PHYSICAL_KEYS = {"ropes", "sample_hz", "frame_hz", "rated_rope_tension_N", "imbalance_frac",
                 "battery_low_V", "cylinder_area_m2", "adc_bits", "pressure_channels", "displacement_channels",
                 "speed_m_per_pulse", "hall_marks_m", "battery_V_per_count", "temperature", "oil_temp_assumed_C",
                 "velocity_cutoff_hz", "friction", "loss"}


@pytest.fixture
def site_dir(tmp_path) -> Path:
    for name in ("paper-site.toml", "paper-friction.json", "paper-compliance.json"):
        shutil.copy(SCEN / name, tmp_path / name)
    return tmp_path


def test_paper_site_gives_a_node_json_the_node_accepts(site_dir, capsys):
    out = site_dir / "node.json"
    assert ropemon(["config", str(site_dir / "paper-site.toml"), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert set(doc) == {"schema", "physical", "node", "crc", "sha256"}
    ph = doc["physical"]
    assert PHYSICAL_KEYS <= set(ph)
    cfg = node_module("config").parse(doc)  # the firmware's own check: schema, CRC, every range
    assert cfg is not None
    # the friction lines are the fit's, unchanged
    fit = json.loads((site_dir / "paper-friction.json").read_text())
    for key in ("Fs", "Fc", "vs", "sigma2"):
        assert ph["friction"][key] == {"slope": fit[key]["slope"], "intercept": fit[key]["intercept"]}
    assert (ph["friction"]["sigma0"], ph["friction"]["sigma1"]) == (fit["sigma0"], fit["sigma1"])
    # per-rope sensor scales and the loss table in the documented shape
    assert ph["pressure_channels"][0]["range_Pa"] == [0.0, 25e6]
    loss = ph["loss"]
    assert len(loss["dp_Pa"]) == 4 and len(loss["dp_Pa"][0]) == len(loss["temps_C"])
    assert ph["oil_temp_assumed_C"] in loss["temps_C"]
    printed = capsys.readouterr().out
    assert f"config CRC 0x{doc['crc']:04x}" in printed and "wrote" in printed
    assert f"SLACK alarm below {0.6 * ph['conveyance_weight_N'] / 4 / 1e3:.1f} kN per rope" in printed


def test_node_loss_table_is_the_physical_one_in_newtons(site_dir):
    site = load_site(site_dir / "paper-site.toml")
    from ropemon.commission.nodejson import make_node_json
    doc = make_node_json(physical_from_site(site))
    ph, nd = doc["physical"], doc["node"]
    area = ph["cylinder_area_m2"][0]
    dp = ph["loss"]["dp_Pa"][0]
    assert nd["loss"]["force_n"][0] == [[round(x * area) for x in row] for row in dp]


def test_same_site_same_bytes(site_dir):
    a, b = site_dir / "a.json", site_dir / "b.json"
    assert ropemon(["config", str(site_dir / "paper-site.toml"), "--out", str(a)]) == 0
    assert ropemon(["config", str(site_dir / "paper-site.toml"), "--out", str(b)]) == 0
    assert a.read_bytes() == b.read_bytes()


def refused(site_dir, capsys, *extra) -> str:
    out = site_dir / "node.json"
    assert ropemon(["config", str(site_dir / "paper-site.toml"), "--out", str(out), *extra]) == 1
    assert not out.exists()
    return capsys.readouterr().err


def test_invalid_site_is_refused_with_field_and_reason(site_dir, capsys):
    p = site_dir / "paper-site.toml"
    p.write_text(p.read_text().replace("bore_m = 0.100", "bore_m = -0.1"))
    assert "config: error: cylinders.bore_m: must be > 0, got -0.1" in refused(site_dir, capsys)


def test_missing_friction_file_is_refused(site_dir, capsys):
    (site_dir / "paper-friction.json").unlink()
    assert "friction.file: cannot read" in refused(site_dir, capsys)


def test_friction_that_goes_unphysical_within_the_tested_range_is_refused(site_dir, capsys):
    fr = json.loads((site_dir / "paper-friction.json").read_text())
    top = fr["pressure_range_MPa"][1]
    fr["vs"]["slope"] = -fr["vs"]["intercept"] / (top - 2)  # vs reaches 0 below the bed's top pressure
    (site_dir / "bad.json").write_text(json.dumps(fr))
    err = refused(site_dir, capsys, "--friction", str(site_dir / "bad.json"))
    assert f"friction.vs: must be > 0 over 0..{top:.2f} MPa" in err


def test_friction_lines_are_held_above_the_tested_pressure_not_extrapolated(site_dir):
    fr = json.loads((site_dir / "paper-friction.json").read_text())
    top = fr["pressure_range_MPa"][1]
    fr["vs"]["slope"] = -fr["vs"]["intercept"] / 20  # vs would reach 0 at 20 MPa, beyond the bed's data
    ph = physical_from_site(load_site(site_dir / "paper-site.toml"), fr)
    assert ph["friction_p_max_MPa"] == top < 20
    assert make_node_json(ph)["node"]["p_kpa_max"] == math.ceil(top * 1000)


def test_node_builder_limits_are_reported_not_hidden(site_dir, capsys):
    # a 4 m bore at 25 MPa is a tension no 32-bit node integer can hold: the builder's refusal
    # comes back as a config error, not a traceback
    p = site_dir / "paper-site.toml"
    text = p.read_text().replace("bore_m = 0.100", "bore_m = 0.9").replace("max_speed_m_s = 0.05", "max_speed_m_s = 0.001")
    p.write_text(text)
    err = refused(site_dir, capsys)
    assert err.startswith("config: error: physical") and "node config built from" in err


def test_friction_extrapolation_is_warned(site_dir, capsys):
    fr = json.loads((site_dir / "paper-friction.json").read_text())
    fr["pressure_range_MPa"] = [2.0, 6.0]
    (site_dir / "low.json").write_text(json.dumps(fr))
    assert ropemon(["config", str(site_dir / "paper-site.toml"), "--out", str(site_dir / "n.json"),
                    "--friction", str(site_dir / "low.json")]) == 0
    assert "the test bed went up to 6 MPa, below the rated-tension pressure 10.19 MPa" in capsys.readouterr().err


def test_rated_pressure_is_tension_over_area():
    site = load_site(SCEN / "paper-site.toml")
    assert site.rated_pressure_MPa == pytest.approx(80e3 / (math.pi * 0.1 ** 2 / 4) / 1e6)


def test_a_seal_stiffer_than_the_node_represents_is_commissioned_at_its_limit(site_dir, capsys):
    """A fit with no measurable pre-sliding (sigma0 ~ 5e10 N/m) gets the node's stiffest
    sigma0 with a warning, and the node accepts the config; a representable one is kept."""
    from ropemon.commission.nodejson import sigma0_max

    fr = json.loads((site_dir / "paper-friction.json").read_text())
    site = load_site(site_dir / "paper-site.toml")
    kept = physical_from_site(site, fr)
    assert kept["friction"]["sigma0"] == fr["sigma0"] < sigma0_max(kept)
    fr["sigma0"], fr["sigma1"] = 5.4e10, 5.4e7  # fit-friction's default sigma1 = 1 ms x sigma0
    ph = physical_from_site(site, fr)
    assert ph["friction"]["sigma0"] == sigma0_max(ph) < 5.4e10
    assert ph["friction"]["sigma1"] == pytest.approx(1e-3 * ph["friction"]["sigma0"])
    doc = make_node_json(ph)
    assert node_module("config").parse(doc).ropes == 4
    (site_dir / "stiff.json").write_text(json.dumps(fr))
    assert ropemon(["config", str(site_dir / "paper-site.toml"), "--friction", str(site_dir / "stiff.json"),
                    "--out", str(site_dir / "stiff-node.json")]) == 0
    assert "fitted sigma0 5.4e+10 N/m is stiffer than the node represents" in capsys.readouterr().err


def test_a_seal_that_releases_its_force_at_standstill_is_refused(site_dir, capsys):
    """fit-friction's standstill_hold_ratio: a LuGre seal holds ~0.9 of its sliding force when
    the bed's piston stops; one that holds none is not what the node models, and refused."""
    fr = json.loads((site_dir / "paper-friction.json").read_text())
    site = load_site(site_dir / "paper-site.toml")
    for ratio in (0.89, None):  # held, or not measured (a record without a standstill)
        doc = dict(fr, standstill_hold_ratio=ratio) if ratio is not None else fr
        assert physical_from_site(site, doc)["friction"]["sigma0"] == fr["sigma0"]
    (site_dir / "released.json").write_text(json.dumps(dict(fr, standstill_hold_ratio=0.0004)))
    err = refused(site_dir, capsys, "--friction", str(site_dir / "released.json"))
    assert "friction.standstill_hold_ratio: the seal held 0 % of its sliding force" in err
    assert "refused" in err
    # the evaluation still builds what a node forced onto it would hold
    ph = physical_from_site(site, dict(fr, standstill_hold_ratio=0.0004), refuse_unheld=False)
    assert ph["friction"]["sigma0"] == fr["sigma0"]


def test_empty_load_is_a_host_only_key_the_node_ignores(site_dir):
    """The slack-rope alarm's figures travel in `physical`; node section and CRC do not change."""
    site = load_site(site_dir / "paper-site.toml")
    ph = physical_from_site(site)
    # the cage alone (8.18 t): at the shaft bottom the tail ropes hang on the other side of
    # their loop, so this, not the 185.4 kN pithead load, is the least a head-rope set carries
    assert ph["conveyance_weight_N"] == pytest.approx(8180 * 9.81)
    assert ph["rated_load_N"] == pytest.approx(site.hoist.rated_load_N)
    assert ph["slack_frac"] == site.alarms.slack_frac
    with_keys = make_node_json(ph)
    without = make_node_json({k: v for k, v in ph.items() if k not in ("conveyance_weight_N", "slack_frac")})
    assert with_keys["node"] == without["node"] and with_keys["crc"] == without["crc"]
    assert node_module("config").parse(with_keys) is not None


def test_config_says_when_the_seals_are_too_strong_for_the_band_to_vouch_for_the_limit(site_dir, capsys):
    """The paper's worn seal can hold more than a tenth of a rope's load: `ropemon config` prints
    the imbalance the seals can hide at the empty and the rated rope tension, and warns that it is
    beyond the limit: the hoist's standing status on every face, what to do about it."""
    from ropemon.commission.config_cli import deviation_cover

    assert ropemon(["config", str(site_dir / "paper-site.toml"), "--out", str(site_dir / "node.json")]) == 0
    cap = capsys.readouterr()
    site = load_site(site_dir / "paper-site.toml")
    ph = json.loads((site_dir / "node.json").read_text())["physical"]
    c = deviation_cover(ph, site.hoist.empty_load_N / 4, site.hoist.rated_rope_tension_N)
    assert c["empty_reach"] > 0.1 and c["rated_reach"] > 0.1
    line = next(x for x in cap.out.splitlines() if x.startswith("hidden imbalance"))
    assert "the hoist's standing status, shown on every face" in line
    assert (f"hide an imbalance of up to {c['empty_reach']:.1%} with the cage empty at the pithead "
            f"({site.hoist.empty_load_N / 4e3:.1f} kN a rope)") in line
    assert f"up to {c['rated_reach']:.1%} at the rated rope tension (80.0 kN)" in line and "limit is 10%" in line
    assert "hidden imbalance: the seals can hide an imbalance of up to" in cap.err
    assert "beyond the 10% limit" in cap.err and "standing status on every face (not an alarm)" in cap.err
    assert "lower-friction seals" in cap.err and "by other means" in cap.err
    assert "DEVIATION POSSIBLE" not in cap.err + cap.out


def test_config_prints_the_stroke_margins(site_dir, capsys):
    assert ropemon(["config", str(site_dir / "paper-site.toml"), "--out", str(site_dir / "node.json")]) == 0
    out = capsys.readouterr().out
    assert ("stroke 200 mm (every rope): end stops at -100.0 and +100.0 mm from mid-stroke; margin 10.0 mm: "
            "the stroke-limit band starts at -90.0 mm (retracted) and +90.0 mm (extended); travel tolerance "
            "5.0 mm: a reading beyond +-105.0 mm is the displacement channel's fault") in out
    from ropemon.commission.config_cli import stroke_lines
    ph = json.loads((site_dir / "node.json").read_text())["physical"]
    ph2 = dict(ph, stroke_m=[0.2, 0.2, 0.3, 0.2], stroke_margin_m=0.02, travel_tolerance_m=0.0)
    assert stroke_lines(ph2) == [
        "stroke 200 mm (rope 1, 2, 4): end stops at -100.0 and +100.0 mm from mid-stroke; margin 20.0 mm: the "
        "stroke-limit band starts at -80.0 mm (retracted) and +80.0 mm (extended); travel tolerance 0.0 mm: a "
        "reading beyond +-100.0 mm is the displacement channel's fault",
        "stroke 300 mm (rope 3): end stops at -150.0 and +150.0 mm from mid-stroke; margin 20.0 mm: the "
        "stroke-limit band starts at -130.0 mm (retracted) and +130.0 mm (extended); travel tolerance 0.0 mm: a "
        "reading beyond +-150.0 mm is the displacement channel's fault"]
    bare = {k: v for k, v in ph.items() if k not in ("stroke_m", "stroke_margin_m", "travel_tolerance_m")}
    assert stroke_lines(bare) == ["stroke: not known (no stroke_m): no stroke limit is checked"]


def test_stroke_and_zero_reach_the_node_section(site_dir):
    """stroke_m, stroke_margin_m and travel_tolerance_m go into `physical` and the node's
    stroke keys (um/256 from mid-stroke); zero_m is folded into the channel's range_m, so the
    node's position (and the float reference's) is from mid-stroke."""
    from docedit import edited
    import tomllib
    from ropemon.commission.site import parse_site

    site = load_site(site_dir / "paper-site.toml")
    ph = physical_from_site(site)
    assert (ph["stroke_m"], ph["stroke_margin_m"], ph["travel_tolerance_m"]) == ([0.2] * 4, 0.01, 0.005)
    nd = make_node_json(ph)["node"]
    assert nd["stroke_lo_q8um"] == [round(-0.09 * 256e6)] * 4 == [-23040000] * 4
    assert nd["stroke_hi_q8um"] == [23040000] * 4
    assert nd["travel_lo_q8um"] == [-26880000] * 4 and nd["travel_hi_q8um"] == [26880000] * 4
    doc = tomllib.loads((site_dir / "paper-site.toml").read_text())
    d = edited(edited(doc, "sensors.displacement.zero_m", 0.02), "cylinders.stroke_margin_m", 0.015)
    d = edited(d, "sensors.displacement.travel_tolerance_m", 0.0)
    site2 = parse_site(d, site_dir / "paper-site.toml")
    ph2 = physical_from_site(site2)
    assert ph2["displacement_channels"][0]["range_m"] == pytest.approx([-0.12, 0.08])
    nd2 = make_node_json(ph2)["node"]
    assert nd2["displacement"][0]["q8um_at_lo"] == round(-0.12 * 256e6)
    assert nd2["displacement"][0]["q8um_mul"] == nd["displacement"][0]["q8um_mul"]  # the scale is unchanged
    assert nd2["stroke_lo_q8um"][0] == round(-0.085 * 256e6) and nd2["travel_hi_q8um"][0] == round(0.1 * 256e6)
    assert node_module("config").parse(make_node_json(ph2)) is not None
    # the transmitter reads 0.02 m at mid-stroke: the node's position there is 0
    ch = site2.sensors.displacement[0]
    counts_mid = ch.counts_lo + (0.02 - ch.range_m[0]) / (ch.range_m[1] - ch.range_m[0]) * (ch.counts_hi - ch.counts_lo)
    d0 = nd2["displacement"][0]
    x_q8um = d0["q8um_at_lo"] + ((round(counts_mid) - d0["counts_lo"]) * d0["q8um_mul"] >> d0["q8um_shift"])
    assert abs(x_q8um) < 256 * 10  # within 10 um (a count is 5 um)


def test_deviation_cover_hand_checked():
    """Four equal ropes of 40 kN, Fs flat, no residual: S = 1.25 Fs. Fs = 2 kN: S = 2.5 kN,
    d_max = 4 x 42.5 / (42.5 + 3 x 37.5) - 1 = 9.68 %; Fs = 2.2 kN: 4 x 42.75 / (42.75 + 3 x 37.25) - 1
    = 10.68 %."""
    from ropemon.commission.config_cli import deviation_cover

    def physical(fs):
        return {"ropes": 4, "cylinder_area_m2": [0.008] * 4, "imbalance_frac": 0.1,
                "friction": {"Fs": {"intercept": fs, "slope": 0.0}, "Fc": {"intercept": fs, "slope": 0.0},
                             "residual": 0.0}}
    c = deviation_cover(physical(2000.0), 40e3, 40e3)
    assert c["empty_s_N"] == pytest.approx(2500.0)
    assert c["empty_reach"] == pytest.approx(170 / 155 - 1) and c["empty_reach"] < c["limit"]
    c = deviation_cover(physical(2200.0), 40e3, 40e3)
    assert c["rated_reach"] == pytest.approx(171 / 154.5 - 1) and c["rated_reach"] > c["limit"]
    assert deviation_cover({"ropes": 4, "cylinder_area_m2": 0.008}, 40e3, 40e3) is None


def test_node_json_is_written_readable_by_its_owner_only(site_dir, capsys):
    """node.json holds the node's key: created with mode 0600 (never a wider mode first), also
    over an earlier file that others could read, and the output says so."""
    import os
    import stat

    out = site_dir / "node.json"
    out.write_text("an earlier, world-readable file")
    out.chmod(0o644)
    old = os.umask(0o022)
    try:
        assert ropemon(["config", str(site_dir / "paper-site.toml"), "--out", str(out)]) == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE(out.stat().st_mode) == 0o600
    assert f"wrote {out} (mode 0600, readable by its owner only: it holds node 1's key)" in capsys.readouterr().out
    assert [p.name for p in site_dir.iterdir() if p.name.startswith(".")] == []  # no temporary file left


def test_the_node_id_and_key_are_in_the_node_section_only(site_dir):
    """One copy of the identity, the one the node reads; the host reads it there too."""
    from ropemon.station.protocol import load_node_keys

    out = site_dir / "node.json"
    assert ropemon(["config", str(site_dir / "paper-site.toml"), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    site = load_site(site_dir / "paper-site.toml")
    assert "node_id" not in doc["physical"] and "key_hex" not in doc["physical"]
    assert (doc["node"]["node_id"], bytes(doc["node"]["key"])) == (site.node_id, site.key)
    assert load_node_keys(out) == {site.node_id: site.key}


def test_a_site_with_the_simulators_plant_table_is_refused(site_dir, capsys):
    """[plant] (the hidden hoist) belongs to the simulator's scenarios, never to SITE.toml."""
    import tomllib

    p = site_dir / "paper-site.toml"
    p.write_text(p.read_text() + "\n[plant]\nfriction = \"paper\"\n")
    err = refused(site_dir, capsys)
    assert "config: error: plant: unknown field" in err
    scenarios = [s for s in SCEN.glob("*.toml") if "rig" in tomllib.loads(s.read_text())]
    assert len(scenarios) >= 5
    for scenario in scenarios:  # the scenarios keep theirs; the site description has none
        assert "plant" in tomllib.loads(scenario.read_text()), scenario
    assert "plant" not in tomllib.loads((SCEN / "paper-site.toml").read_text())


def test_config_warns_when_a_transmitter_cannot_read_into_a_stroke_band(site_dir):
    """+-100 mm transmitters read -105 .. +112.5 mm (3.6 .. 21 mA): the 200 mm stroke's bands
    (from -+90 mm) are readable. With zero_m = 0.03 (mid-stroke reads +30 mm) the transmitter
    reads -135 .. +82.5 mm from mid-stroke: short of the extended band, which starts at +90 mm."""
    import tomllib

    from docedit import edited
    from ropemon.commission.config_cli import stroke_warnings
    from ropemon.commission.site import parse_site

    path = site_dir / "paper-site.toml"
    assert stroke_warnings(load_site(path)) == []
    doc = tomllib.loads(path.read_text())
    w = stroke_warnings(parse_site(edited(doc, "sensors.displacement.zero_m", 0.03), path))
    assert w == [f"stroke: rope {i}'s displacement transmitter reads only to +82.5 mm from mid-stroke, short of "
                 "the extended end's stroke-limit band (from +90.0 mm): a piston there shows as the transmitter's "
                 "fault, not as a stroke limit" for i in range(1, 5)]
    w = stroke_warnings(parse_site(edited(doc, "sensors.displacement.zero_m", -0.02), path))
    assert len(w) == 4 and "reads only to -85.0 mm" in w[0] and "retracted end's stroke-limit band (from -90.0 mm)" in w[0]
