"""The config builder: shipped default, canonical form, refusals naming the field."""
from __future__ import annotations

import json
import math

import pytest

from ropemon.firmware import FIRMWARE_DIR, node_module
from ropemon.nodeconfig import build_node_section, example_physical, make_node_json

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
    (("key_hex",), "physical.key_hex"),
    (("velocity_cutoff_hz",), "physical.velocity_cutoff_hz"),
    (("speed_m_per_pulse",), "physical.speed_m_per_pulse"),
])
def test_builder_refuses_with_the_field_named(change, field):
    ph = example_physical()
    bad = {"Fs": 5000.0, "sigma0": 5e9, "cylinder_area_m2": [0.09] * 4, "key_hex": "abcd",
           "velocity_cutoff_hz": 150.0, "speed_m_per_pulse": 5.0}[change[-1] if change[-1] != "slope" else "Fs"]
    d = ph
    for k in change[:-1]:
        d = d[k]
    d[change[-1]] = bad
    with pytest.raises(ValueError) as e:
        build_node_section(ph)
    assert str(e.value).startswith(field), str(e.value)


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
