"""The scenario variants of issue 6 are the field trip with exactly one change."""
import pytest

from ropemon import evaluate as ev


def base(tmp_path):
    return ev.scenario_doc(ev.FIELD_TRIP, tmp_path)[0]


def test_every_default_scenario_resolves(tmp_path):
    for name in ev.DEFAULT_SCENARIOS:
        doc, path = ev.scenario_doc(name, tmp_path / name)
        assert path.exists() and doc["plant"]


def test_oil_variants_change_only_the_oil_temperature(tmp_path):
    doc = ev.scenario_doc("oil-0C", tmp_path)[0]
    ref = base(tmp_path)
    assert doc["plant"]["oil_temp_C"] == 0.0
    doc["plant"]["oil_temp_C"] = ref["plant"]["oil_temp_C"]
    doc["name"] = ref["name"]
    assert doc == ref


def test_temperature_input_variant_fits_the_input_in_a_site_copy(tmp_path):
    from ropemon.site import load_site

    doc = ev.scenario_doc("oil-40C-temp-input", tmp_path)[0]
    site = load_site(doc["site"])
    assert site.sensors.temperature is not None
    assert site.friction_path.exists()


def test_payload_and_duty_variants(tmp_path):
    loads = [p for p in ev.scenario_doc("payload-12t", tmp_path)[0]["trip"]["phase"] if p["kind"] == "load"]
    assert [p["payload_kg"] for p in loads] == [12000.0, 0.0]  # loaded at the bottom, unloaded at the top
    duty = ev.scenario_doc("duty-cycle-50", tmp_path)[0]
    assert "trip" not in duty and duty["duty"]["trips"] == 50


def test_other_friction_variant_builds_a_plant_law(tmp_path):
    from ropemon.plant.friction import CoulombStribeck, from_table

    fr = ev.scenario_doc("plant-other-friction", tmp_path)[0]["plant"]["friction"]
    assert isinstance(from_table(fr, "plant.friction"), CoulombStribeck)


def test_keep_vs_positive_tilts_only_a_line_that_crosses_zero():
    fit = {"vs": {"intercept": 0.004, "slope": -0.0002}, "pressure_range_MPa": [2.0, 12.0]}
    note = ev.keep_vs_positive(fit, 25.0)
    assert note and "tilted" in note
    vs = fit["vs"]
    assert vs["intercept"] + vs["slope"] * 7.0 == pytest.approx(0.004 - 0.0014)   # unchanged mid value
    assert vs["intercept"] + vs["slope"] * 25.0 == pytest.approx(0.25 * 0.0026)   # the floor at the top
    flat = {"vs": {"intercept": 0.004, "slope": -0.0001}, "pressure_range_MPa": [2.0, 12.0]}
    assert ev.keep_vs_positive(flat, 25.0) is None and flat["vs"]["slope"] == -0.0001
