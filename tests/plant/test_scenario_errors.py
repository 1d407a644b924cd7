"""Bad scenario files are refused with the field and the reason."""
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from ropemon.lab.plant.scenario import ScenarioError, load_scenario


def _write(tmp_path, scenarios_dir, text):
    # the site file sits beside the scenario, as in scenarios/
    for f in ("paper-site.toml", "paper-friction.json", "paper-compliance.json"):
        shutil.copy(scenarios_dir / f, tmp_path / f)
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return p


def _field_trip_text(scenarios_dir):
    return (scenarios_dir / "paper-field-trip.toml").read_text()


@pytest.mark.parametrize("old,new,field", [
    ("beta_Pa = 0.9e9", "beta_Pa = -1.0", "plant.beta_Pa"),
    ("step_s = 0.005", 'step_s = 0.005\nmethod = "rk4"', "method"),
    ("beta_Pa = 0.9e9", 'beta_Pa = "stiff"', "plant.beta_Pa"),
    ("EA_N = 7.1e7", "EA_N = 0", "plant.ropes.EA_N"),
    ("offsets_m = [0.012, -0.004, 0.0, -0.010]", "offsets_m = [0.012, 0.0]", "plant.ropes.offsets_m"),
    ("offsets_m = [0.012, -0.004, 0.0, -0.010]", "offsets_m = [0.5, 0.0, 0.0, 0.0]", "plant.ropes.offsets_m"),
    ("offsets_m = [0.012, -0.004, 0.0, -0.010]", "groove_creep = [1e-4, 0.0, 0.0, 0.0]", "plant.ropes.groove_creep"),
    ("offsets_m = [0.012, -0.004, 0.0, -0.010]", "groove_creep = [0.0, 0.0]", "plant.ropes.groove_creep"),
    ('law = "lugre"', 'law = "magic"', "plant.friction.law"),
    ("sigma0 = 1.0e8", "", "plant.friction.sigma0"),
    ("Fs = { intercept = 2500.0, slope = 2000.0 }", "Fs = 2500.0", "plant.friction.Fs"),
    ('kind = "wind"', 'kind = "fly"', "trip.phase[3].kind"),
    ("to_depth_m = 2.0", "to_depth_m = 9000.0", "trip.phase[3].to_depth_m"),
    ("duration_s = 3.0", "duration_s = 0", "trip.phase[0].duration_s"),
    ('site = "paper-site.toml"', 'site = "missing-site.toml"', "site"),
    ('rig = "hoist"', 'rig = "crane"', "rig"),
    ("oil_temp_C = 12.0", "oil_temp_C = 300.0", "plant.oil_temp_C"),
    ("[plant.ropes]", "[plant.ropes]\nEA = 1", "plant.ropes.EA"),
    ("pressure_noise_Pa = 5000.0", "pressure_noise_Pa = -1.0", "sensors.pressure_noise_Pa"),
])
def test_bad_field_is_named(tmp_path, scenarios_dir, old, new, field):
    text = _field_trip_text(scenarios_dir)
    assert old in text
    p = _write(tmp_path, scenarios_dir, text.replace(old, new, 1))
    with pytest.raises(ScenarioError) as e:
        load_scenario(p)
    assert str(e.value).startswith(field), str(e.value)


def test_not_toml_and_missing_file(tmp_path, scenarios_dir):
    p = _write(tmp_path, scenarios_dir, "name = [unclosed")
    with pytest.raises(ScenarioError, match="not valid TOML"):
        load_scenario(p)
    with pytest.raises(ScenarioError, match="cannot read"):
        load_scenario(tmp_path / "nope.toml")


def test_fault_fields_are_checked(tmp_path, scenarios_dir):
    text = _field_trip_text(scenarios_dir) + '\n[[sensors.fault]]\nkind = "melt"\nrope = 1\n'
    with pytest.raises(ScenarioError, match=r"^sensors\.fault\[0\]\.kind"):
        load_scenario(_write(tmp_path, scenarios_dir, text))
    text = _field_trip_text(scenarios_dir) + '\n[[sensors.fault]]\nkind = "stuck"\nrope = 7\n'
    with pytest.raises(ScenarioError, match=r"^sensors\.fault\[0\]\.rope"):
        load_scenario(_write(tmp_path, scenarios_dir, text))


def test_cli_refuses_with_exit_1_and_the_field(tmp_path, scenarios_dir):
    text = _field_trip_text(scenarios_dir).replace("EA_N = 7.1e7", "EA_N = -5")
    p = _write(tmp_path, scenarios_dir, text)
    r = subprocess.run([sys.executable, "-m", "ropemon.cli", "simulate", str(p), "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert "plant.ropes.EA_N" in r.stderr
    assert not (tmp_path / "o").exists()
