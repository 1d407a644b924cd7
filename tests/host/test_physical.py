"""node.json's `physical` section: one check (ropemon.station.physical) for what commissioning
writes, what the node's builder reads and what the station reads; every refusal names the field."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

import docedit
from ropemon.commission.nodejson import seal
from ropemon.firmware import FIRMWARE_DIR
from ropemon.station.physical import Physical, PhysicalError, load_node_json
from ropemon.station.nodefigures import NodeFigures, alarm_settings, figures_from_configs

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = json.loads((FIRMWARE_DIR / "node.json").read_text())["physical"]


def edited(path: str, value=..., delete: bool = False) -> dict:
    """The shipped section with one dotted field set (or deleted); list items as [i]."""
    return docedit.edited(SHIPPED, path, value, delete)


A = SHIPPED["cylinder_area_m2"][0]
BAD = [
    # (field edited, new value, expected message start)
    ("imbalance_frac", math.nan, "physical.imbalance_frac: must be finite, got nan"),
    ("imbalance_frac", 0.6, "physical.imbalance_frac: must be <= 0.5, got 0.6"),
    ("imbalance_frac", 0, "physical.imbalance_frac: must be > 0, got 0"),
    ("imbalance_frac", True, "physical.imbalance_frac: must be a number, got True"),
    ("rated_rope_tension_N", math.inf, "physical.rated_rope_tension_N: must be finite, got inf"),
    ("rated_rope_tension_N", "100 kN", "physical.rated_rope_tension_N: must be a number, got '100 kN'"),
    ("rated_rope_tension_N", 50.0, "physical.rated_rope_tension_N: must be >= 1000"),
    ("battery_low_V", 100.0, "physical.battery_low_V: must be <= 65, got 100"),
    ("battery_low_V", -3.4, "physical.battery_low_V: must be > 0"),
    # the node's id and key are the node section's only (one copy, the one the node reads)
    ("node_id", 1, "physical.node_id: not here: the node's id is `node.node_id` only"),
    ("key_hex", "00" * 16, "physical.key_hex: not here: the node's key is `node.key` only"),
    ("ropes", 5, "physical.ropes: must be <= 4, got 5"),        # the frame carries at most 4 (layout.MAX_ROPES)
    ("ropes", 0, "physical.ropes: must be >= 1, got 0"),
    ("ropes", 3, "physical.cylinder_area_m2: must have 3 entries"),  # every per-rope list disagrees
    ("ropes", 4.0, "physical.ropes: must be an integer, got 4.0"),
    ("sample_hz", 200.0, "physical.sample_hz: must be an integer, got 200.0"),
    ("sample_hz", 5000, "physical.sample_hz: must be <= 1000"),
    ("frame_hz", 7, "physical.frame_hz: sample_hz (200) must be a multiple of it, got 7"),
    ("cylinder_area_m2", [A] * 3, "physical.cylinder_area_m2: must have 4 entries"),
    ("cylinder_area_m2", A, "physical.cylinder_area_m2: must be a list"),
    ("cylinder_area_m2", [A, A, A, 0.0], "physical.cylinder_area_m2[3]: must be >= 0.0001, got 0"),
    ("cylinder_area_m2", [A, A, -A, A], "physical.cylinder_area_m2[2]: must be >= 0.0001"),
    ("cylinder_area_m2", [A, A, A, math.nan], "physical.cylinder_area_m2[3]: must be finite"),
    ("pressure_channels", SHIPPED["pressure_channels"][:3], "physical.pressure_channels: must have 4 entries"),
    ("pressure_channels[1].counts_20mA", 100, "physical.pressure_channels[1].counts_20mA: must be > counts_4mA"),
    ("pressure_channels[1].counts_4mA", 9600.0, "physical.pressure_channels[1].counts_4mA: must be an integer"),
    ("pressure_channels[0].range_Pa", [25e6, 0.0], "physical.pressure_channels[0].range_Pa: high must be > low"),
    ("pressure_channels[0].range_Pa", [0.0, math.inf], "physical.pressure_channels[0].range_Pa: must be finite"),
    ("pressure_channels[0].gain", 1.0, "physical.pressure_channels[0].gain: unknown field"),
    ("pressure_channels[3]", "4-20 mA", "physical.pressure_channels[3]: must be a table"),
    ("displacement_channels[2].counts_hi", 70000, "physical.displacement_channels[2].counts_hi: must be <= 65535"),
    ("displacement_channels[2].counts_hi", 9600, "physical.displacement_channels[2].counts_hi: must be > counts_lo"),
    ("adc_bits", 12, "physical.pressure_channels[0].counts_4mA: must be <= 4095"),
    ("adc_bits", 24, "physical.adc_bits: must be <= 16"),
    ("speed_m_per_pulse", 0.0, "physical.speed_m_per_pulse: must be >= 1e-05"),
    ("hall_marks_m", [5.0, 2.0], "physical.hall_marks_m: must be strictly ascending"),
    ("hall_marks_m", [float(m) for m in range(65)], "physical.hall_marks_m: must have 0..64 entries"),
    ("temperature", {"counts_at_0C": 8000.0, "counts_per_C": 0.0}, "physical.temperature.counts_per_C: must not be 0"),
    ("temperature", {"counts_at_0C": 8000.0}, "physical.temperature.counts_per_C: missing"),
    ("temperature", 20.0, "physical.temperature: must be a table"),
    ("oil_temp_assumed_C", 400.0, "physical.oil_temp_assumed_C: must be <= 150"),
    ("velocity_cutoff_hz", 150.0, "physical.velocity_cutoff_hz: must be <= 100, got 150"),
    ("velocity_cutoff_hz", 0.5, "physical.friction_cutoff_hz: must be <= 0.5, got 1"),  # as written in the shipped file
    ("friction.Fs.intercept", math.nan, "physical.friction.Fs.intercept: must be finite"),
    ("friction.Fc.intercept", 5000.0, "physical.friction.Fs: must be >= Fc"),
    ("friction.vs.slope", -0.01, "physical.friction.vs: must be > 0 over 0..26.56 MPa"),
    ("friction.sigma0", 0.0, "physical.friction.sigma0: must be > 0"),
    ("friction.sigma1", -1.0, "physical.friction.sigma1: must be >= 0"),
    ("friction.Fs.unit", "N", "physical.friction.Fs.unit: unknown field"),
    ("friction.residual", -5.0, "physical.friction.residual: must be >= 0"),
    ("friction.Fs", 1500.0, "physical.friction.Fs: missing or not an object"),
    ("loss.dp_Pa", SHIPPED["loss"]["dp_Pa"][:3], "physical.loss.dp_Pa: must have 4 entries"),
    ("loss.dp_Pa[0]", SHIPPED["loss"]["dp_Pa"][0][:2], "physical.loss.dp_Pa[0]: must have 3 temperature rows"),
    ("loss.dp_Pa[0][0][1]", -5.0, "physical.loss.dp_Pa[0][0][1]: must be >= 0"),
    ("loss.temps_C", [20.0, 0.0, 40.0], "physical.loss.temps_C: must be 1..8 ascending"),
    ("loss.flow_m3_s[0]", 1e-5, "physical.loss.flow_m3_s: must start at 0"),
    ("hydraulic_compliance_m_per_Pa", [3e-10] * 3, "physical.hydraulic_compliance_m_per_Pa: must have 4 entries"),
    ("hydraulic_compliance_m_per_Pa", [2e-6] * 4, "physical.hydraulic_compliance_m_per_Pa[0]: must be <= 1e-06"),
    ("friction_cutoff_hz", 6.0, "physical.friction_cutoff_hz: must be <= 5, got 6"),
    ("friction_play_sigmas", -1.0, "physical.friction_play_sigmas: must be >= 0"),
    ("bounce_hz", 30.0, "physical.bounce_hz: must be <= 25, got 30"),
    ("slide_follow", 1, "physical.slide_follow: must be true or false, got 1"),
    ("slide_follow_hi_sigmas", 2.0, "physical.slide_follow_hi_sigmas: 2 must exceed slide_follow_lo_sigmas 3"),
    ("pressure_cutoff_hz", 5.0, "physical.pressure_cutoff_hz: no longer used"),
    ("friction_p_max_MPa", 30.0, "physical.friction_p_max_MPa: must be <= 26.5625"),
    ("conveyance_weight_N", -1, "physical.conveyance_weight_N: must be > 0, got -1"),
    ("slack_frac", 1.0, "physical.slack_frac: must be < 1, got 1"),
    ("overload_frac", 0.9, "physical.overload_frac: must be >= 1, got 0.9"),
    ("overload_frac", 3.0, "physical.overload_frac: must be <= 2, got 3"),
    ("rated_load_N", "lots", "physical.rated_load_N: must be a number"),
    ("band_anchor", 1, "physical.band_anchor: must be true or false, got 1"),
    ("band_gain", 11.0, "physical.band_gain: 11.0 out of range"),
    ("friction_residual_frac", {"sliding": -0.1}, "physical.friction_residual_frac.sliding: must be >= 0"),
    ("friction_residual_frac", {"slidng": 0.1}, "physical.friction_residual_frac.slidng: unknown field"),
    ("colour", "red", "physical.colour: unknown field"),
]


@pytest.mark.parametrize("field,value,message", BAD, ids=[f"{f}={v!r}"[:60] for f, v, _ in BAD])
def test_a_bad_value_is_refused_naming_the_field_and_the_reason(field, value, message):
    with pytest.raises(PhysicalError) as e:
        Physical.from_dict(edited(field, value))
    assert str(e.value).startswith(message), str(e.value)


@pytest.mark.parametrize("field", ["ropes", "friction", "loss", "temperature",
                                   "pressure_channels", "loss.dp_Pa", "friction.Fc.slope"])
def test_a_missing_required_key_is_refused(field):
    with pytest.raises(PhysicalError, match=rf"^physical\.{field.replace('.', chr(92) + '.')}: missing"):
        Physical.from_dict(edited(field, delete=True))
    with pytest.raises(PhysicalError, match=r"^physical\.friction\.sigma1: must be a number, got None"):
        Physical.from_dict(edited("friction.sigma1", delete=True))


def test_with_a_compliance_the_rest_play_must_cover_the_play():
    d = dict(SHIPPED, hydraulic_compliance_m_per_Pa=[3e-10] * 4, friction_play_sigmas=9.0)
    with pytest.raises(PhysicalError, match=r"^physical\.rest_play_sigmas: must be at least friction_play_sigmas"):
        Physical.from_dict(d)
    del d["friction_play_sigmas"]
    assert Physical.from_dict(d).setting("rest_play_sigmas") == 4.5  # the compliance's default


def test_the_caller_names_where_the_section_came_from():
    with pytest.raises(PhysicalError, match=r"^node-7\.json: physical\.overload_frac: must be >= 1"):
        Physical.from_dict(dict(SHIPPED, overload_frac=0.5), "node-7.json: physical")
    with pytest.raises(PhysicalError, match=r"^node-7\.json: physical\.band_margin"):
        Physical.from_dict(dict(SHIPPED, band_margin=-1.0), "node-7.json: physical")
    with pytest.raises(PhysicalError, match=r"^physical: must be a table, got list"):
        Physical.from_dict([SHIPPED])


def test_the_shipped_section_round_trips():
    p = Physical.from_dict(SHIPPED)
    assert p.to_dict() == SHIPPED
    assert Physical.from_dict(p.to_dict()) == p
    assert p.ropes == 4 and p.temperature is None and not p.has_compliance
    assert p.setting("friction_play_sigmas") == SHIPPED["friction_play_sigmas"]
    assert p.setting("rest_sigmas") == 0.0          # no rest hold without a compliance
    k = Physical.from_dict(dict(SHIPPED, hydraulic_compliance_m_per_Pa=[3e-10] * 4))
    assert k.setting("noise_follow_s") == 20.0 and k.setting("friction_cutoff_hz") == SHIPPED["friction_cutoff_hz"]


def test_a_full_section_with_every_optional_key_round_trips():
    d = dict(SHIPPED, temperature={"counts_at_0C": 8000.0, "counts_per_C": 160.0}, adc_bits=16,
             hydraulic_compliance_m_per_Pa=[3e-10, 3.1e-10, 2.9e-10, 3e-10], pressure_noise_Pa=5200.0,
             bounce_hz=2.6, slide_follow=False, friction_residual_frac={"sliding": 0.02, "presliding": 0.05},
             friction_p_max_MPa=20.0, conveyance_weight_N=80_000.0, slack_frac=0.6, rated_load_N=300_000.0,
             overload_frac=1.1, band_anchor=True, band_margin=0.1,
             friction=dict(SHIPPED["friction"], residual=40.0))
    p = Physical.from_dict(d)
    assert p.to_dict() == d and Physical.from_dict(p.to_dict()) == p
    assert p.friction.residual == 40.0 and p.friction_p_max_Pa == 20e6 and p.rated_total_N == 300_000.0
    assert p.band().anchor is True and p.band().margin == 0.1


def test_what_config_writes_for_every_scenario_site_is_what_the_station_reads(tmp_path):
    """`ropemon config`'s physical section (commission.site) is built through Physical and
    comes back out of node.json as the same Physical."""
    pytest.importorskip("fluids")
    from ropemon.commission.nodejson import make_node_json
    from ropemon.commission.site import load_site, physical_from_site

    sites = sorted({p for p in (ROOT / "scenarios").glob("*.toml") if "[hoist]" in p.read_text()})
    assert sites
    for path in sites:
        ph = physical_from_site(load_site(path))
        out = tmp_path / f"{path.stem}.json"
        out.write_text(json.dumps(make_node_json(ph)))
        p, doc = load_node_json(out)
        assert p.to_dict() == ph and doc["physical"] == ph
        assert NodeFigures.from_node_json(out) == NodeFigures.from_physical(p)


def test_the_shipped_node_json_loads_and_gives_the_station_its_figures():
    p, doc = load_node_json(FIRMWARE_DIR / "node.json")
    assert doc["physical"] == SHIPPED and p == Physical.from_dict(SHIPPED)
    site = figures_from_configs([str(FIRMWARE_DIR / "node.json")])
    assert site.cylinder_area_m2 == SHIPPED["cylinder_area_m2"] and site.rated_load_n == 4 * 100_000.0
    assert site.band is not None and site.overload_frac == 1.0 and site.conveyance_weight_n is None
    settings = alarm_settings(site)
    assert settings.rated_load_dan == 40_000 and settings.slack_dan is None


def test_node_json_reading_refuses_what_is_not_a_node_config(tmp_path):
    with pytest.raises(PhysicalError, match=r"/dev/zero: larger than 4 MB"):
        load_node_json("/dev/zero")
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 200_000 + "]" * 200_000)
    with pytest.raises(PhysicalError, match=r"deep\.json: nested too deeply"):
        load_node_json(deep)
    for text, message in (("{", "not valid JSON"), ("[1, 2]", "not a node config"), ('{"node": {}}', "not a node config"),
                          ("\xff\xfe", "not valid JSON")):
        bad = tmp_path / "bad.json"
        bad.write_text(text, encoding="latin-1")
        with pytest.raises(PhysicalError, match=message):
            load_node_json(bad)
    with pytest.raises(PhysicalError, match=r"absent\.json: cannot read"):
        load_node_json(tmp_path / "absent.json")
    nan = tmp_path / "nan.json"   # JSON's NaN extension parses; the section refuses it
    nan.write_text(json.dumps(seal({"physical": dict(SHIPPED, imbalance_frac=math.nan)})))
    with pytest.raises(PhysicalError, match=r"nan\.json: physical\.imbalance_frac: must be finite, got nan"):
        NodeFigures.from_node_json(nan)


def test_the_monitor_refuses_configs_of_different_hoists(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(seal({"physical": SHIPPED})))
    b.write_text(json.dumps(seal({"physical": dict(SHIPPED, imbalance_frac=0.2)})))
    assert figures_from_configs([str(a), str(a)]) == NodeFigures.from_node_json(a)
    with pytest.raises(ValueError, match="describe different hoists"):
        figures_from_configs([str(a), str(b)])


# ---------------------------------------------------------------- the file as `ropemon config` wrote it


def test_a_physical_section_changed_after_config_wrote_it_is_refused(tmp_path):
    """node.json's `sha256` covers `physical` (which the node never sees) as the node's CRC covers
    `node`: a hand edit or a corruption is refused before anything in the file is used."""
    from ropemon.station.protocol import load_node_keys

    doc = json.loads((FIRMWARE_DIR / "node.json").read_text())
    edited_file = tmp_path / "node.json"
    edited_file.write_text(json.dumps(dict(doc, physical=dict(SHIPPED, imbalance_frac=0.2))))  # still valid
    for read in (load_node_json, NodeFigures.from_node_json, lambda p: figures_from_configs([str(p)]), load_node_keys):
        with pytest.raises(PhysicalError, match=r"^\S*node\.json: changed after `ropemon config` wrote it "
                                                 r"\(its `sha256` does not match"):
            read(edited_file)
    # the node section too (the host reads the node's id and key there)
    nd = dict(doc["node"], key=[0] * 16)
    edited_file.write_text(json.dumps(dict(doc, node=nd)))
    with pytest.raises(PhysicalError, match="changed after `ropemon config` wrote it"):
        load_node_keys(edited_file)
    # without its digest: not a file `ropemon config` wrote
    edited_file.write_text(json.dumps({k: v for k, v in doc.items() if k != "sha256"}))
    with pytest.raises(PhysicalError, match=r"node\.json: no `sha256`: not a node\.json written by `ropemon config`"):
        load_node_json(edited_file)
    # layout is not content: the same document indented otherwise still loads
    edited_file.write_text(json.dumps(doc, indent=4))
    assert load_node_json(edited_file)[0] == Physical.from_dict(SHIPPED)


def test_the_node_id_and_key_have_one_copy_the_node_section_which_host_and_node_read():
    from ropemon.commission.nodejson import EXAMPLE_KEY, EXAMPLE_NODE_ID
    from ropemon.firmware import node_module
    from ropemon.station.physical import node_identity
    from ropemon.station.protocol import load_node_keys

    doc = json.loads((FIRMWARE_DIR / "node.json").read_text())
    assert "node_id" not in doc["physical"] and "key_hex" not in doc["physical"]
    cfg = node_module("config").parse(doc)
    assert load_node_keys(FIRMWARE_DIR / "node.json") == {cfg.node_id: cfg.key} == {EXAMPLE_NODE_ID: EXAMPLE_KEY}
    for nd, message in (({"node_id": 256, "key": [1] * 16}, r"x\.json: node\.node_id: must be an integer 0\.\.255"),
                        ({"node_id": True, "key": [1] * 16}, r"node\.node_id: must be an integer"),
                        ({"node_id": 1, "key": [1] * 15}, r"x\.json: node\.key: must be 16\.\.32 bytes"),
                        ({"node_id": 1, "key": "00" * 16}, r"node\.key: must be 16\.\.32 bytes")):
        with pytest.raises(PhysicalError, match=message):
            node_identity({"node": nd}, "x.json")


STROKE = {"stroke_m": [0.1] * 4, "stroke_margin_m": 0.01, "travel_tolerance_m": 0.005}


@pytest.mark.parametrize("change,message", [
    ({"stroke_m": [0.1] * 3}, "physical.stroke_m: must have 4 entries (strokes in m, one per rope), got 3"),
    ({"stroke_m": [0.1, 0.1, 0.0, 0.1]}, "physical.stroke_m[2]: must be > 0, got 0"),
    ({"stroke_m": [0.1, 0.1, 11.0, 0.1]}, "physical.stroke_m[2]: must be <= 4, got 11"),
    ({"stroke_margin_m": 0.0}, "physical.stroke_margin_m: must be > 0, got 0"),
    ({"stroke_margin_m": 0.025}, "physical.stroke_margin_m: must be < 0.025, got 0.025"),
    ({"stroke_m": [0.1, 0.1, 0.04, 0.1], "stroke_margin_m": 0.011}, "physical.stroke_margin_m: must be < 0.01"),
    ({"stroke_m": [0.03] * 4, "stroke_margin_m": None},
     "physical.stroke_margin_m: the default 0.01 m is not below stroke_m/4 = 0.0075 m here; give a value"),
    ({"travel_tolerance_m": -0.001}, "physical.travel_tolerance_m: must be >= 0"),
    ({"travel_tolerance_m": 0.06}, "physical.travel_tolerance_m: must be <= 0.05"),
    ({"travel_tolerance_m": math.nan}, "physical.travel_tolerance_m: must be finite"),
    ({"stroke_m": None}, "physical.stroke_margin_m: needs stroke_m"),
])
def test_the_stroke_fields_are_range_checked(change, message):
    bare = {k: v for k, v in SHIPPED.items() if k not in STROKE}
    d = {k: v for k, v in {**bare, **STROKE, **change}.items() if v is not None or k == "temperature"}
    with pytest.raises(PhysicalError) as e:
        Physical.from_dict(d)
    assert str(e.value).startswith(message), str(e.value)


def test_the_stroke_reaches_the_station_and_defaults():
    p = Physical.from_dict({**SHIPPED, **STROKE})
    assert p.stroke_m == (0.1,) * 4 and (p.stroke_margin, p.travel_tolerance) == (0.01, 0.005)
    assert Physical.from_dict(p.to_dict()) == p
    f = NodeFigures.from_physical(p)
    assert f.stroke_m == [0.1] * 4 and f.stroke_margin_m == 0.01
    bare = {k: v for k, v in SHIPPED.items() if k not in STROKE}
    p = Physical.from_dict({**bare, "stroke_m": [0.2, 0.2, 0.3, 0.2]})  # margin and tolerance by default
    assert (p.stroke_margin_m, p.stroke_margin, p.travel_tolerance) == (None, 0.01, 0.005)
    p = Physical.from_dict(bare)  # a node.json written before the stroke was known
    assert p.stroke_m is None and p.stroke_margin is None and p.travel_tolerance is None
    f = NodeFigures.from_physical(p)
    assert f.stroke_m == [] and f.stroke_margin_m is None
    assert NodeFigures().stroke_m == [] and NodeFigures().stroke_margin_m is None
