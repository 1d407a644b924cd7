"""SITE.toml loading: the example loads, and every bad field is refused by name and reason."""
from __future__ import annotations

import copy
import math
import tomllib
from pathlib import Path

import pytest

from docedit import edited
from ropemon.commission.site import SiteError, check_friction, load_site, parse_site

ROOT = Path(__file__).resolve().parents[2]
PAPER_SITE = ROOT / "scenarios" / "paper-site.toml"


@pytest.fixture(scope="module")
def doc() -> dict:
    with PAPER_SITE.open("rb") as f:
        return tomllib.load(f)


def test_paper_site_loads_with_the_papers_hoist():
    site = load_site(PAPER_SITE)
    h = site.hoist
    assert (h.ropes, h.tail_ropes, h.shaft_depth_m, h.cage_mass_kg) == (4, 2, 810.0, 8180.0)
    # the domain brief's check: empty cage + 2 tail ropes at the pithead = 185.4 kN
    assert h.empty_load_N == pytest.approx(185.4e3, rel=1e-3)
    assert len(site.cylinders) == len(site.pipes) == len(site.sensors.pressure) == 4
    assert site.cylinders[0].area_m2 == pytest.approx(math.pi * 0.1 ** 2 / 4)
    assert site.pipes[0].length_m > site.pipes[1].length_m  # end ropes have longer hoses
    assert site.oil.temp_assumed_C in site.oil.table_temps_C
    assert site.friction_path == PAPER_SITE.parent / "paper-friction.json"
    assert site.sensors.temperature is None


BAD = [
    # (field edited, new value, expected message start)
    ("cylinders.bore_m", -0.1, "cylinders.bore_m: must be > 0, got -0.1"),
    ("cylinders.area_m2", 0.02, "cylinders.area_m2: must not exceed pi*bore^2/4"),
    ("hoist.ropes", 5, "hoist.ropes: must be <= 4, got 5"),
    ("hoist.ropes", 4.0, "hoist.ropes: must be an integer"),
    ("hoist.rated_rope_tension_N", 50000.0, "hoist.rated_rope_tension_N: must be >= the rated load per rope"),
    ("hoist.shaft_depth_m", "810", "hoist.shaft_depth_m: must be a number"),
    ("hoist.rope_count", 4, "hoist.rope_count: unknown field"),
    ("alarms.imbalance_frac", 1.5, "alarms.imbalance_frac: must be < 1"),
    ("pipes[1].segments[1].bore_m", 0.0, "pipes[1].segments[1].bore_m: must be > 0"),
    ("pipes[2].fittings[0].kind", "elbow", "pipes[2].fittings[0].kind: must be one of"),
    ("pipes[0].fittings[0].from_bore_m", 0.008, "pipes[0].fittings[0].from_bore_m: a contraction must come from"),
    ("pipes[0].fittings[1].angle_deg", 60, "pipes[0].fittings[1].angle_deg: must be 45, 90 or 180"),
    ("pipes[0].fittings[2].valve", "needle", "pipes[0].fittings[2].valve: must be one of"),
    ("pipes[3].segments", [], "pipes[3].segments: must be a non-empty array"),
    ("oil.iso_vg", 47, "oil.iso_vg: not an ISO 3448 grade"),
    ("oil.temp_assumed_C", 200.0, "oil.temp_assumed_C: must be <= 120"),
    ("sensors.pressure.counts_20mA", 4000, "sensors.pressure.counts_20mA: must be > counts_4mA"),
    ("sensors.pressure.counts_20mA", 65000, "sensors.pressure.counts_20mA: the ADC must read 3.6..21 mA"),
    ("sensors.pressure.range_MPa", [0.0, 10.0], "sensors.pressure[0].range_MPa: top 10 MPa is below 130 %"),
    ("sensors.pressure.range_MPa", [25.0, 0.0], "sensors.pressure.range_MPa: high must be > low"),
    ("sensors.displacement.range_m", [-0.5, 0.5], "sensors.displacement.range_m: span 1 m exceeds"),
    ("cylinders.stroke_margin_m", 0.0, "cylinders.stroke_margin_m: must be > 0, got 0"),
    ("cylinders.stroke_margin_m", 0.05, "cylinders.stroke_margin_m: must be < stroke_m/4 = 0.05 m"),
    ("cylinders.stroke_margin_m", "10 mm", "cylinders.stroke_margin_m: must be a number"),
    ("cylinders.stroke_m", 20.0, "cylinders.stroke_m: must be <= 4, got 20"),
    ("sensors.displacement.zero_m", 0.15, "sensors.displacement.zero_m: the channel's reading at mid-stroke must "
                                          "be within its range_m -0.1..0.1 m, got 0.15"),
    ("sensors.displacement.zero_m", math.nan, "sensors.displacement.zero_m: must be finite"),
    ("sensors.displacement.travel_tolerance_m", -0.001, "sensors.displacement.travel_tolerance_m: must be >= 0"),
    ("sensors.displacement.travel_tolerance_m", 0.2, "sensors.displacement.travel_tolerance_m: must be <= 0.1"),
    ("sensors.displacement.zero_mm", 0.0, "sensors.displacement.zero_mm: unknown field"),
    ("sensors.hall_marks_m", [2.0, 808.0, 405.0], "sensors.hall_marks_m: must be strictly ascending"),
    ("sensors.adc_bits", 24, "sensors.adc_bits: must be <= 16"),
    ("rates.frame_hz", 7, "rates.frame_hz: sample_hz (200) must be a multiple of it"),
    ("rates.velocity_cutoff_hz", 150.0, "rates.velocity_cutoff_hz: must be below sample_hz/2"),
    ("node.id", 256, "node.id: must be <= 255"),
    ("node.key_hex", "xyz", "node.key_hex: must be hexadecimal"),
    ("node.key_hex", "0011", "node.key_hex: key must be 16..32 bytes, got 2"),
]


@pytest.mark.parametrize("path,value,message", BAD, ids=[b[0] + "=" + repr(b[1]) for b in BAD])
def test_bad_field_is_refused_by_name_and_reason(doc, path, value, message):
    with pytest.raises(SiteError) as e:
        parse_site(edited(doc, path, value), PAPER_SITE)
    assert str(e.value).startswith(message), str(e.value)


@pytest.mark.parametrize("path", ["hoist.ropes", "cylinders.stroke_m", "rates.sample_hz", "node.id", "oil"])
def test_missing_field_is_named(doc, path):
    with pytest.raises(SiteError, match=rf"^{path.replace('.', '[.]')}: missing"):
        parse_site(edited(doc, path, delete=True), PAPER_SITE)


def test_per_rope_arrays_must_match_the_rope_count(doc):
    d = edited(doc, "pipes", doc["pipes"][:3])
    with pytest.raises(SiteError, match=r"^pipes: must have one entry per rope \(4\), got 3"):
        parse_site(d, PAPER_SITE)


def test_per_rope_array_of_cylinders_is_accepted(doc):
    cyl = [dict(doc["cylinders"]) for _ in range(4)]
    cyl[2]["bore_m"] = 0.11
    site = parse_site(edited(doc, "cylinders", cyl), PAPER_SITE)
    assert site.cylinders[2].bore_m == 0.11 and site.cylinders[0].bore_m == 0.1


def test_stroke_fields_and_their_defaults(doc):
    site = parse_site(doc, PAPER_SITE)
    assert [c.stroke_margin_m for c in site.cylinders] == [0.01] * 4
    assert [(c.zero_m, c.travel_tolerance_m) for c in site.sensors.displacement] == [(0.0, 0.005)] * 4
    d = edited(edited(doc, "cylinders.stroke_margin_m", delete=True), "sensors.displacement.travel_tolerance_m",
               delete=True)
    d = edited(d, "sensors.displacement.zero_m", delete=True)
    site = parse_site(d, PAPER_SITE)  # the documented defaults
    assert site.cylinders[0].stroke_margin_m == 0.01 and site.sensors.displacement[0].travel_tolerance_m == 0.005
    assert site.sensors.displacement[0].zero_m == 0.0
    site = parse_site(edited(doc, "sensors.displacement.zero_m", 0.025), PAPER_SITE)
    assert site.sensors.displacement[0].range_from_mid_m == pytest.approx((-0.125, 0.075))


def test_the_node_holds_one_margin_and_one_tolerance_for_all_ropes(doc):
    cyl = [dict(doc["cylinders"]) for _ in range(4)]
    cyl[1]["stroke_margin_m"] = 0.02
    with pytest.raises(SiteError, match=r"^cylinders.stroke_margin_m: must be the same for every rope "
                                        r"\(one stroke margin\), got 0.01, 0.02, 0.01, 0.01"):
        parse_site(edited(doc, "cylinders", cyl), PAPER_SITE)
    disp = [dict(doc["sensors"]["displacement"]) for _ in range(4)]
    disp[3]["travel_tolerance_m"] = 0.01
    with pytest.raises(SiteError, match=r"^sensors.displacement.travel_tolerance_m: must be the same for every"):
        parse_site(edited(doc, "sensors.displacement", disp), PAPER_SITE)
    disp = [dict(doc["sensors"]["displacement"]) for _ in range(4)]
    disp[2]["zero_m"] = 0.003  # a zero per transmitter is fine
    site = parse_site(edited(doc, "sensors.displacement", disp), PAPER_SITE)
    assert [c.zero_m for c in site.sensors.displacement] == [0.0, 0.0, 0.003, 0.0]
    cyl = [dict(doc["cylinders"]) for _ in range(4)]
    cyl[0]["stroke_m"] = 0.03  # the default margin 0.01 is not below 0.03/4 for this cylinder
    disp = [dict(doc["sensors"]["displacement"], range_m=[-0.015, 0.015]) for _ in range(4)]
    with pytest.raises(SiteError, match=r"^cylinders\[0\].stroke_margin_m: must be < stroke_m/4 = 0.0075 m"):
        parse_site(edited(edited(doc, "cylinders", cyl), "sensors.displacement", disp), PAPER_SITE)


def test_key_from_file_and_not_both(doc, tmp_path):
    (tmp_path / "node.key").write_text("a5" * 32 + "\n")
    d = edited(doc, "node", {"id": 3, "key_file": "node.key"})
    assert parse_site(d, tmp_path / "site.toml").key_hex == "a5" * 32
    d = edited(doc, "node", {"id": 3, "key_file": "absent.key"})
    with pytest.raises(SiteError, match=r"^node.key_file: cannot read"):
        parse_site(d, tmp_path / "site.toml")
    d = edited(doc, "node", {"id": 3, "key_file": "node.key", "key_hex": "00" * 16})
    with pytest.raises(SiteError, match=r"^node.key_file: give either key_hex or key_file"):
        parse_site(d, tmp_path / "site.toml")


def test_oil_by_datasheet_viscosities(doc):
    oil = {"viscosity_40C_cSt": 68.0, "viscosity_100C_cSt": 8.7, "temp_assumed_C": 15.0}
    site = parse_site(edited(doc, "oil", oil), PAPER_SITE)
    assert site.oil.iso_vg is None and site.oil.viscosity_40C_cSt == 68.0
    assert 15.0 in site.oil.table_temps_C
    bad = dict(oil, viscosity_100C_cSt=80.0)
    with pytest.raises(SiteError, match=r"^oil.viscosity_100C_cSt: must be below the 40 C viscosity"):
        parse_site(edited(doc, "oil", bad), PAPER_SITE)


def test_unreadable_and_invalid_toml(tmp_path):
    with pytest.raises(SiteError, match="cannot read"):
        load_site(tmp_path / "absent.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[hoist\nropes = 4\n")
    with pytest.raises(SiteError, match="not valid TOML"):
        load_site(bad)


LINES = {"Fs": {"slope": 1000.0, "intercept": 2000.0}, "Fc": {"slope": 600.0, "intercept": 1200.0},
         "vs": {"slope": -0.0003, "intercept": 0.012}, "sigma2": {"slope": 3000.0, "intercept": 20000.0},
         "sigma0": 5e7, "sigma1": 5e4}


def test_friction_must_stay_physical_over_the_sensor_range():
    assert check_friction(LINES, 25.0)["vs"]["slope"] == -0.0003
    steep = copy.deepcopy(LINES)
    steep["vs"]["slope"] = -0.0006  # vs < 0 above 20 MPa
    with pytest.raises(SiteError, match=r"^friction.vs: must be > 0 over 0..25.00 MPa"):
        check_friction(steep, 25.0)
    crossed = copy.deepcopy(LINES)
    crossed["Fc"]["intercept"] = 2500.0
    with pytest.raises(SiteError, match=r"^friction.Fs: must be >= Fc"):
        check_friction(crossed, 25.0)
    no_s0 = {k: v for k, v in LINES.items() if k != "sigma0"}
    with pytest.raises(SiteError, match=r"^friction.sigma0: must be a number"):
        check_friction(no_s0, 25.0)


def test_physical_needs_a_friction_fit(doc):
    from ropemon.commission.site import physical_from_site
    site = parse_site(edited(doc, "friction", delete=True), PAPER_SITE)
    with pytest.raises(SiteError, match=r"^friction.file: missing \(run `ropemon fit-friction`"):
        physical_from_site(site)
    ph = physical_from_site(site, LINES)
    assert ph["friction"] == {k: LINES[k] for k in ("Fs", "Fc", "vs", "sigma2", "sigma0", "sigma1")}
    assert ph["cylinder_area_m2"] == [c.area_m2 for c in site.cylinders]
    assert ph["pressure_channels"][0] == {"counts_4mA": 9600, "counts_20mA": 48000, "range_Pa": [0.0, 25e6]}
