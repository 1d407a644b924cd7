"""The scenario variants of issue 6 are the field trip with exactly one change."""
import numpy as np
import pytest

from ropemon.lab import evaluate as ev


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
    from ropemon.commission.site import load_site

    doc = ev.scenario_doc("oil-40C-temp-input", tmp_path)[0]
    site = load_site(doc["site"])
    assert site.sensors.temperature is not None
    assert site.friction_path.exists()


def test_quiet_sensors_variant_quarters_the_pressure_noise_and_sets_the_sites_play(tmp_path):
    from ropemon.commission.site import load_site, physical_from_site

    doc = ev.scenario_doc("quiet-sensors", tmp_path)[0]
    ref = base(tmp_path)
    assert doc["sensors"]["pressure_noise_Pa"] == ref["sensors"]["pressure_noise_Pa"] / 4
    assert doc["sensors"]["adc_noise_counts"] == ref["sensors"]["adc_noise_counts"] / 4
    doc["sensors"].update(pressure_noise_Pa=ref["sensors"]["pressure_noise_Pa"],
                          adc_noise_counts=ref["sensors"]["adc_noise_counts"])
    site = load_site(doc.pop("site"))
    ref.pop("site")
    doc["name"] = ref["name"]
    assert doc == ref  # nothing else changed
    assert site.play_sigmas == 1.6 and site.compliance_path.exists() and site.friction_path.exists()
    assert physical_from_site(site)["friction_play_sigmas"] == 1.6


def test_noise_drift_variant_is_commissioned_at_the_field_trips_noise(tmp_path, monkeypatch):
    doc = ev.scenario_doc("pressure-noise-drift", tmp_path)[0]
    ref = base(tmp_path)
    assert doc["sensors"]["pressure_noise_Pa"] == 1.2 * ref["sensors"]["pressure_noise_Pa"]
    doc["sensors"]["pressure_noise_Pa"] = ref["sensors"]["pressure_noise_Pa"]
    doc["name"] = ref["name"]
    assert doc == ref  # nothing else changed
    # its commissioning wind is recorded at the field trip's noise; another variant's at its own
    seen = {}

    def fake_simulate(name, out_dir, seed, change=None):
        wind = ev.scenario_doc(name, out_dir)[0]
        change(wind)
        seen[name] = wind["sensors"]["pressure_noise_Pa"]
        raise ev.EvaluationError("stop here")

    monkeypatch.setattr(ev, "simulate", fake_simulate)
    for name in ("pressure-noise-drift", "quiet-sensors"):
        with pytest.raises(ev.EvaluationError, match="stop here"):
            ev.fit_compliance(name, {}, tmp_path / name, 1)
    assert seen == {"pressure-noise-drift": ref["sensors"]["pressure_noise_Pa"],
                    "quiet-sensors": ref["sensors"]["pressure_noise_Pa"] / 4}


def test_payload_and_duty_variants(tmp_path):
    loads = [p for p in ev.scenario_doc("payload-12t", tmp_path)[0]["trip"]["phase"] if p["kind"] == "load"]
    assert [p["payload_kg"] for p in loads] == [12000.0, 0.0]  # loaded at the bottom, unloaded at the top
    duty = ev.scenario_doc("duty-cycle-50", tmp_path)[0]
    assert "trip" not in duty and duty["duty"]["trips"] == 50


def test_long_rest_and_open_loop_variants(tmp_path):
    rests = [p for p in ev.scenario_doc("pithead-long-rest", tmp_path)[0]["trip"]["phase"] if p["kind"] == "rest"]
    assert rests[-1]["duration_s"] == 120.0 and rests[-1]["label"] == "pithead rest empty"
    assert [p["duration_s"] for p in rests[:-1]] == [3.0, 4.0, 10.0]  # the others as on the field trip
    fault = ev.scenario_doc("pressure-loop-open", tmp_path)[0]["sensors"]["fault"]
    assert fault == [{"kind": "open_loop", "channel": "pressure", "rope": 1, "start_s": 30.0}]


def test_an_absent_rope_in_a_firmware_frame_is_not_scored():
    """A frame marks a rope with no healthy sample in its window absent (TENSION_ABSENT):
    its mean is NaN for the scoring, not -32768 daN."""
    from ropemon.station import protocol as P

    rope = P.Rope(4000, 3990, 4010, 5000)
    gone = P.Rope(P.L.TENSION_ABSENT, P.L.TENSION_ABSENT, P.L.TENSION_ABSENT, P.L.RAW_KPA_ABSENT)

    class F:  # what frame_means_n reads of a decoded frame
        def __init__(self, ropes):
            self.ropes = ropes

    m = ev.frame_means_n([F((rope, rope)), F((rope, gone))])
    assert m.shape == (2, 2) and m[0, 0] == 40000.0 and m[1, 0] == 40000.0
    assert np.isnan(m[1, 1]) and not np.isnan(m[0, 1])


def test_other_friction_variant_builds_a_plant_law(tmp_path):
    from ropemon.lab.plant.friction import CoulombStribeck, from_table

    fr = ev.scenario_doc("plant-other-friction", tmp_path)[0]["plant"]["friction"]
    assert isinstance(from_table(fr, "plant.friction"), CoulombStribeck)


def test_the_hidden_seal_reaches_the_bed_as_a_scenario_file(tmp_path):
    """The seal the bed runs is the scenario's own, read by ropemon.lab.testbed.scenario_seal."""
    from ropemon.lab import testbed

    for name in (ev.FIELD_TRIP, "plant-other-friction"):
        fr = ev.scenario_doc(name, tmp_path)[0]["plant"]["friction"]
        params, factory = testbed.scenario_seal(ev.write_seal(fr, tmp_path / f"{name}.seal.toml"))
        if fr["law"] == "lugre":
            assert factory is None and params["sigma0"] == fr["sigma0"] and params["vs"] == fr["vs"]
        else:
            assert params is None and factory is not None


def test_the_node_is_commissioned_from_a_fitted_sigma0(tmp_path):
    """The quick bed keeps the slow reversals stretched to the seal's vs: sigma0 is fitted
    (the plant's is 1e8 N/m; fit-friction's default would be 1.65e8) and the node takes the config."""
    fr = ev.scenario_doc(ev.FIELD_TRIP, tmp_path)[0]["plant"]["friction"]
    fit = ev.fit_plant_seal(fr, tmp_path, seed=1, bed=ev.BED_QUICK)
    assert fit["presliding"]["source"] in ev.SIGMA0_FITTED
    assert fit["sigma0"] == pytest.approx(fr["sigma0"], rel=0.05)
    assert fit["bed"]["presliding_period_s"] > 4.0   # stretched: vs is 2.9 mm/s at 11 MPa
    assert fit["vs"]["slope"] == pytest.approx(fr["vs"]["slope"], rel=0.5)   # no tilt: as fitted


def test_a_default_sigma0_or_a_refused_config_is_a_commissioning_failure():
    fit = {"presliding": {"source": "default (no pre-sliding data)"}, "sigma0": 1.65e8}
    problems = ev.commissioning_problems(fit, {"ropes": 4})
    assert any("sigma0 NOT fitted" in pr for pr in problems)
    assert any(pr.startswith("the node refuses the commissioned config: physical.") for pr in problems)
