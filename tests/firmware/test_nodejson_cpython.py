"""The config builder: shipped default, canonical form, refusals naming the field."""
from __future__ import annotations

import json
import math

import pytest

from ropemon.firmware import FIRMWARE_DIR, node_module
from ropemon.commission.nodejson import (COMPLIANCE_DEFAULTS, MEDIAN_NOISE, build_node_section, example_physical,
                                make_node_json, tracker_gains)

config = node_module("config")


def test_shipped_node_json_is_the_builder_default():
    shipped = json.loads((FIRMWARE_DIR / "node.json").read_text())
    assert shipped == json.loads(json.dumps(make_node_json(example_physical())))


def test_canonical_equals_sorted_compact_json():
    nd = build_node_section(example_physical())
    assert config.canonical(nd) == json.dumps(nd, sort_keys=True, separators=(",", ":")).encode()


def test_example_reads_about_15_percent_low_at_the_pithead():
    ph = example_physical()
    area = ph["cylinder_area_m2"][0]
    t_rope = (8180 + 2 * 6.62 * 810) * 9.81 / 4           # empty cage at the pithead
    p_mpa = t_rope / area / 1e6
    fs = ph["friction"]["Fs"]["intercept"] + ph["friction"]["Fs"]["slope"] * p_mpa
    assert 5 <= p_mpa <= 8 and 0.12 <= fs / t_rope <= 0.18  # friction can hold ~15 % of T


@pytest.mark.parametrize("change,field", [
    (("friction", "Fs", "slope"), "physical.friction.Fs"),        # Fs beyond 32 kN at 26 MPa
    (("friction", "sigma0"), "physical.friction.sigma0"),          # w per step beyond 2**19
    (("cylinder_area_m2",), "physical.cylinder_area_m2"),          # tension beyond 2**19 N
    (("velocity_cutoff_hz",), "physical.velocity_cutoff_hz"),
    (("speed_m_per_pulse",), "physical.speed_m_per_pulse"),
])
def test_builder_refuses_with_the_field_named(change, field):
    ph = example_physical()
    bad = {"Fs": 5000.0, "sigma0": 5e9, "cylinder_area_m2": [0.09] * 4,
           "velocity_cutoff_hz": 150.0, "speed_m_per_pulse": 5.0}[change[-1] if change[-1] != "slope" else "Fs"]
    d = ph
    for k in change[:-1]:
        d = d[k]
    d[change[-1]] = bad
    with pytest.raises(ValueError) as e:
        build_node_section(ph)
    assert str(e.value).startswith(field), str(e.value)


def test_the_node_id_and_key_go_into_the_node_section_only():
    """One copy of the identity: the node section's, which the node reads (and the host too)."""
    ph = example_physical()
    assert "node_id" not in ph and "key_hex" not in ph
    doc = make_node_json(ph, node_id=7, key=bytes(range(20)))
    assert (doc["node"]["node_id"], doc["node"]["key"]) == (7, list(range(20)))
    assert "node_id" not in doc["physical"] and "key_hex" not in doc["physical"]
    cfg = config.parse(doc)
    assert (cfg.node_id, cfg.key) == (7, bytes(range(20)))
    for kw, message in (({"key": bytes.fromhex("abcd")}, "key: must be 16..32 bytes, got 2"),
                        ({"key": bytes(33)}, "key: must be 16..32 bytes, got 33"),
                        ({"node_id": 256}, "node_id: must be an integer 0..255, got 256"),
                        ({"node_id": True}, "node_id: must be an integer 0..255, got True")):
        with pytest.raises(ValueError) as e:
            build_node_section(ph, **kw)
        assert str(e.value).startswith(message), str(e.value)


def test_the_document_digest_covers_everything_but_itself():
    from ropemon.station.physical import check_digest, document_digest
    doc = make_node_json(example_physical())
    assert doc["sha256"] == document_digest(doc) and len(doc["sha256"]) == 64
    check_digest(json.loads(json.dumps(doc, indent=1)), "node.json")  # written and read back
    for part, edit in (("physical", lambda d: d["physical"].update(imbalance_frac=0.11)),
                       ("node", lambda d: d["node"].update(node_id=2)),
                       ("crc", lambda d: d.update(crc=d["crc"] ^ 1)),
                       ("schema", lambda d: d.update(schema=2))):
        bad = json.loads(json.dumps(doc))
        edit(bad)
        with pytest.raises(ValueError, match="changed after `ropemon config` wrote it"):
            check_digest(bad, "node.json")


def test_every_product_bound_is_checked_by_the_node_too():
    """A hand-edited node section beyond the builder's bounds is refused at boot."""
    nd = build_node_section(example_physical())
    nd["friction"]["sigma0_mul"] = 2047
    nd["friction"]["sigma0_shift"] = 0
    with pytest.raises(config.ConfigError) as e:
        config.parse_node(nd)
    assert e.value.field == "node.friction.sigma0_mul"


def test_gexp_table():
    nd = build_node_section(example_physical())
    t = nd["friction"]["gexp_q14"]
    assert t[0] == 16384 and t[-1] == 0 and t[32] == round(math.exp(-1) * 16384)
    assert all(a >= b for a, b in zip(t, t[1:]))


@pytest.mark.parametrize("key,bad", [
    ("friction_cutoff_hz", 6.0),        # above velocity_cutoff_hz (5 Hz)
    ("friction_cutoff_hz", 0.0),
    ("friction_play_sigmas", -1.0),
    ("friction_play_sigmas", 11.0),
    ("displacement_noise_m", -1e-6),
    ("displacement_noise_m", "20 um"),
    ("rest_sigmas", -0.5),
    ("rest_play_sigmas", 1.0),          # narrower than the play (2.0) with the rest hold on
    ("rest_cutoff_hz", 0.0),
    ("rest_slow_cutoff_hz", 150.0),     # above sample_hz / 2
    ("slide_follow", 1),                # true or false
    ("slide_follow_lo_sigmas", -1.0),
    ("slide_follow_hi_sigmas", 2.0),    # not above lo (3)
    ("slide_follow_hi_sigmas", 101.0),
])
def test_lugre_observer_keys_are_range_checked(key, bad):
    ph = example_physical()
    ph["hydraulic_compliance_m_per_Pa"] = [3e-10] * 4  # the rest hold runs with a compliance
    ph[key] = bad
    with pytest.raises(ValueError) as e:
        build_node_section(ph)
    assert str(e.value).startswith(f"physical.{key}"), str(e.value)


def test_lugre_observer_defaults_and_integers():
    """Missing keys take the documented defaults; the play is the set sigmas of the
    position noise after both low-passes (20 um transmitter noise + 10.4 um counts)."""
    ph = example_physical()
    for key in ("friction_cutoff_hz", "displacement_noise_m", "friction_play_sigmas"):
        del ph[key]
    fr = build_node_section(ph)["friction"]
    assert fr["alpha_z_q14"] == round((1 - math.exp(-2 * math.pi * 1.0 / 200)) * 16384)
    # white noise through x_f (5 Hz) then x_s (1 Hz) at 200 Hz: rms gain 0.1134 (by simulation)
    noise = math.hypot(2e-5, 0.1 / 38400 / math.sqrt(12))
    expect = 2.0 * 0.1134 * noise * 256e6  # um/256, in steps of 0.01 um (2.56)
    # one play per count of healthy pressure channels: without a compliance they are all
    # the displacement's
    assert len(fr["play_q8um"]) == 4 and len(set(fr["play_q8um"])) == 1, fr["play_q8um"]
    assert abs(fr["play_q8um"][0] - expect) <= 0.015 * expect + 1.28, (fr["play_q8um"], expect)
    assert fr["compliance_q"] == [0, 0, 0, 0]  # no compliance given
    assert fr["warmup_samples"] == 100  # 0.5 s: b settles from the first samples without seal travel


def test_with_a_compliance_the_play_widens_as_pressure_channels_fail():
    """With a compliance the play is sized for the noise of the median of the healthy
    pressure channels: per count m = 1..4 of them, k times MEDIAN_NOISE[m - 1] times one
    channel's noise (kPa/16 steps included) after the pressure tracker (designed for the
    median of all four), times the sigmas."""
    ph = example_physical()
    ph["hydraulic_compliance_m_per_Pa"] = [3e-10] * 4
    ph["pressure_noise_Pa"] = 5200.0
    ph.pop("friction_play_sigmas")  # the compliance default
    fr = build_node_section(ph)["friction"]
    raw = math.hypot(5200.0, 1e3 / 16 / math.sqrt(12))
    one = raw * tracker_gains(200.0, 2.8, 0.2, 3e9, 3e9, (MEDIAN_NOISE[3] * raw) ** 2)["noise_gain"]
    for m in range(1, 5):
        expect = COMPLIANCE_DEFAULTS["friction_play_sigmas"] * 3e-10 * MEDIAN_NOISE[m - 1] * one * 256e6
        # half a 0.01 um play step (1.28) and half a count of um/256
        assert abs(fr["play_q8um"][m - 1] - expect) <= 1.78, (m, fr["play_q8um"], expect)
    assert fr["play_q8um"][0] > fr["play_q8um"][1] > fr["play_q8um"][2] > fr["play_q8um"][3]


def test_node_runs_the_observer_values_the_reference_uses():
    """The node packs alpha_z/play from its validated config, not from built-in defaults."""
    kernel = node_module("kernel")
    ph = example_physical()
    ph["friction_play_sigmas"] = 3.0
    nd = build_node_section(ph)
    cfg = config.parse_node(nd)
    assert (cfg.alpha_z_q14, list(cfg.play_q8um)) == (nd["friction"]["alpha_z_q14"], nd["friction"]["play_q8um"])
    assert list(cfg.play_q8um) != build_node_section(example_physical())["friction"]["play_q8um"]
    p = kernel.pack(cfg)
    assert cfg.alpha_z_q14 in p
    assert list(p[kernel._PLAYS:kernel._PLAYS + 4]) == nd["friction"]["play_q8um"]


def test_stroke_tracking_needs_a_compliance_and_shares_by_area():
    """Strokes are tracked (a threshold) only with a compliance; the area weights are
    each cylinder over the mean, and a cylinder beyond 0.5 .. 1.5 of it is refused by name."""
    ph = example_physical()
    assert build_node_section(ph)["friction"]["stroke_q8um"] == 0  # no compliance
    ph["hydraulic_compliance_m_per_Pa"] = [3e-10] * 4
    fr = build_node_section(ph)["friction"]
    assert 3000 < fr["stroke_q8um"] < 4500 and fr["area_q8"] == [256] * 4  # ~15 um with 20 um noise
    assert build_node_section(dict(ph, stroke_sigmas=0))["friction"]["stroke_q8um"] == 0
    a = ph["cylinder_area_m2"][0]
    assert build_node_section(dict(ph, cylinder_area_m2=[a, a, a, 1.2 * a]))["friction"]["area_q8"] == [244] * 3 + [293]
    with pytest.raises(ValueError, match=r"cylinder_area_m2\[3\]: 2.00 times"):
        build_node_section(dict(ph, cylinder_area_m2=[a, a, a, 3 * a]))


def test_slide_following_is_built_in_the_noise_of_e_and_refused_when_inconsistent():
    """On by default with a compliance (where strokes are tracked): lo 3 and hi - lo 2
    times e's rms noise (the stroke threshold is 6.5), in um/256; off without strokes, with
    slide_follow false, or both sigmas 0. The node refuses a lo without a span by name."""
    ph = example_physical()
    fr = build_node_section(ph)["friction"]
    assert fr["slide_lo_q8um"] == fr["slide_span_q8um"] == 0  # no compliance: no strokes
    ph["hydraulic_compliance_m_per_Pa"] = [3e-10] * 4
    fr = build_node_section(ph)["friction"]
    sig_e = fr["stroke_q8um"] / 6.5
    assert abs(fr["slide_lo_q8um"] - 3 * sig_e) < 1 and abs(fr["slide_span_q8um"] - 2 * sig_e) < 1
    fr = build_node_section(dict(ph, slide_follow_lo_sigmas=1.0, slide_follow_hi_sigmas=1.5))["friction"]
    assert abs(fr["slide_lo_q8um"] - sig_e) < 1 and abs(fr["slide_span_q8um"] - sig_e / 2) < 1
    for off in ({"slide_follow": False}, {"slide_follow_lo_sigmas": 0, "slide_follow_hi_sigmas": 0},
                {"stroke_sigmas": 0}):
        fr = build_node_section(dict(ph, **off))["friction"]
        assert fr["slide_lo_q8um"] == fr["slide_span_q8um"] == 0, off
    nd = build_node_section(ph)
    nd["friction"]["slide_span_q8um"] = 0
    with pytest.raises(config.ConfigError) as e:
        config.parse_node(nd)
    assert e.value.field == "node.friction.slide_lo_q8um", e.value.field
    nd["friction"]["slide_span_q8um"] = (1 << 20) + 1
    with pytest.raises(config.ConfigError) as e:
        config.parse_node(nd)
    assert e.value.field == "node.friction.slide_span_q8um", e.value.field
    with pytest.raises(ValueError, match=r"^physical.slide_follow_hi_sigmas \(slide following's span"):
        build_node_section(dict(ph, displacement_noise_m=1e-3, stroke_sigmas=0.5, slide_follow_hi_sigmas=100.0))


def test_node_refuses_a_rest_play_narrower_than_the_play():
    ph = example_physical()
    ph["hydraulic_compliance_m_per_Pa"] = [3e-10] * 4
    nd = build_node_section(ph)
    nd["friction"]["rest_play_q8um"][2] = nd["friction"]["play_q8um"][2] - 1
    with pytest.raises(config.ConfigError) as e:
        config.parse_node(nd)
    assert e.value.field == "node.friction.rest_play_q8um[2]", e.value.field


def test_noise_following_is_built_from_the_commissioned_noise_and_refused_when_inconsistent():
    """With a compliance the builder turns the noise following on (noise_follow_s 20 s:
    a low-pass of 4096 samples at 200 Hz) at the level of pressure_noise_Pa as the node
    reads it; 0 turns it off. The node refuses a level without a low-pass (and the reverse)
    and, with following, a rest threshold it could not double."""
    ph = example_physical()
    ph["hydraulic_compliance_m_per_Pa"] = [3e-10] * 4
    ph["pressure_noise_Pa"] = 5000.0
    fr = build_node_section(ph)["friction"]
    level = math.hypot(5000.0, 1e3 / 16 / math.sqrt(12)) * math.sqrt(6) * 0.7975 / 62.5 * 64
    assert fr["noise_shift"] == 12 and fr["noise_ref_q6"] == pytest.approx(level, abs=1)
    off = build_node_section(dict(ph, noise_follow_s=0.0))["friction"]
    assert (off["noise_ref_q6"], off["noise_shift"]) == (0, 0)
    assert build_node_section(example_physical())["friction"]["noise_shift"] == 0  # no compliance
    for key, value, field in (("noise_shift", 0, "noise_shift"), ("noise_ref_q6", 0, "noise_shift"),
                              ("rest_q16um", [1 << 20] * 4, "rest_q16um[0]")):
        nd = build_node_section(ph)
        nd["friction"][key] = value
        with pytest.raises(config.ConfigError) as e:
            config.parse_node(nd)
        assert e.value.field == "node.friction." + field, e.value.field


def test_the_pressure_step_limit_is_derived_written_or_off_and_checked_on_both_sides():
    """Derived: 2 pi bounce_hz T_r / (A f_s) + 6 sqrt(2) noise in counts, rounded up; written
    per Pa; 0: off. The host refuses a negative limit or a recovery beyond 10 s, the node a
    step_recover of 0 or a step_max_counts beyond 65535."""
    from ropemon.station.physical import PhysicalError
    ph = example_physical()
    lim = 2 * math.pi * 2.8 * 100e3 / (ph["cylinder_area_m2"][0] * 200) + 6 * math.sqrt(2) * math.hypot(
        5e3, 62.5 / math.sqrt(12))
    nd = build_node_section(ph)
    assert [c["step_max_counts"] for c in nd["pressure"]] == [math.ceil(lim / (25e6 / 38400))] * 4
    assert nd["step_recover"] == 20
    nd = build_node_section(dict(ph, pressure_step_max_Pa=2e6, pressure_step_recover_s=0.0))
    assert [c["step_max_counts"] for c in nd["pressure"]] == [3072] * 4 and nd["step_recover"] == 1
    assert [c["step_max_counts"] for c in build_node_section(dict(ph, pressure_step_max_Pa=0.0))["pressure"]] == [0] * 4
    for key, v in (("pressure_step_max_Pa", -1.0), ("pressure_step_recover_s", 11.0)):
        with pytest.raises(PhysicalError, match="physical." + key):
            build_node_section(dict(ph, **{key: v}))
    for path, v in ((("step_recover",), 0), (("pressure", 2, "step_max_counts"), 65536)):
        nd = build_node_section(ph)
        d = nd
        for k in path[:-1]:
            d = d[k]
        d[path[-1]] = v
        with pytest.raises(config.ConfigError) as e:
            config.parse_node(nd)
        assert e.value.field == "node." + ".".join(str(k) for k in path).replace(".2.", "[2].")


def test_the_stroke_keys_are_built_in_um_256_from_mid_stroke():
    """stroke_lo/hi: where the margin band starts at the retracted / extended end; travel_lo/hi:
    beyond them a reading is the channel's fault. Per rope, from physical.stroke_m."""
    from ropemon.commission.nodejson import STROKE_OFF_Q8UM, stroke_limits

    ph = dict(example_physical(), stroke_m=[0.1, 0.1, 0.12, 0.1], stroke_margin_m=0.008, travel_tolerance_m=0.002)
    nd = build_node_section(ph)
    assert nd["stroke_lo_q8um"] == [round(-0.042 * 256e6)] * 2 + [round(-0.052 * 256e6), round(-0.042 * 256e6)]
    assert nd["stroke_hi_q8um"][2] == round(0.052 * 256e6) == 13312000
    assert nd["travel_lo_q8um"][0] == -round(0.052 * 256e6) and nd["travel_hi_q8um"][2] == round(0.062 * 256e6)
    assert config.parse_node(nd) is not None
    # the defaults: margin 10 mm, tolerance 5 mm
    d = stroke_limits({k: v for k, v in dict(example_physical(), stroke_m=[0.2] * 4).items()
                       if k not in ("stroke_margin_m", "travel_tolerance_m")})
    assert d["stroke_hi_q8um"] == [round(0.09 * 256e6)] * 4 and d["travel_hi_q8um"] == [round(0.105 * 256e6)] * 4
    # no stroke known: nothing checked, beyond any position a channel can read
    bare = {k: v for k, v in example_physical().items()
            if k not in ("stroke_m", "stroke_margin_m", "travel_tolerance_m")}
    d = stroke_limits(bare)
    assert d == {"stroke_lo_q8um": [-STROKE_OFF_Q8UM] * 4, "stroke_hi_q8um": [STROKE_OFF_Q8UM] * 4,
                 "travel_lo_q8um": [-STROKE_OFF_Q8UM] * 4, "travel_hi_q8um": [STROKE_OFF_Q8UM] * 4}
    assert build_node_section(bare)["stroke_hi_q8um"] == [STROKE_OFF_Q8UM] * 4


def test_a_stroke_beyond_what_the_node_holds_is_refused_by_name():
    """The node holds its stroke and travel limits within +-2**29 um/256 (2.1 m from mid-stroke)."""
    ph = dict(example_physical(), stroke_m=[4.0] * 4, travel_tolerance_m=0.2)
    with pytest.raises(ValueError, match=r"^physical.stroke_m\[0\] \(travel_lo_q8um, um/256\): the node would compute"):
        build_node_section(ph)
