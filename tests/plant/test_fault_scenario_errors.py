"""Bad [[faults]] and [plant.end_stops] entries are refused with the field and the reason."""
import pytest

from ropemon.lab.plant.scenario import ScenarioError, load_scenario

from test_scenario_errors import _field_trip_text, _write


@pytest.mark.parametrize("extra,field,reason", [
    ('[[faults]]\nkind = "valve_open"\nrope = 1\n', "faults[0].kind", "must be one of"),
    ('[[faults]]\nrope = 1\n', "faults[0].kind", "missing"),
    ('[[faults]]\nkind = "valve_closed"\n', "faults[0].rope", "missing"),
    ('[[faults]]\nkind = "valve_closed"\nrope = 0\n', "faults[0].rope", ">= 1"),
    ('[[faults]]\nkind = "valve_closed"\nrope = 5\n', "faults[0].rope", "<= 4"),
    ('[[faults]]\nkind = "valve_closed"\nrope = 2\nside = "pump"\n', "faults[0].side", "must be one of"),
    ('[[faults]]\nkind = "valve_closed"\nrope = 2\nat_s = -1.0\n', "faults[0].at_s", ">= 0"),
    ('[[faults]]\nkind = "valve_closed"\nrope = 2\nat_s = 500.0\n', "faults[0].at_s", "after the scenario's end"),
    ('[[faults]]\nkind = "valve_closed"\nrope = 2\nfactor = 3.0\n', "faults[0].factor", "unknown field"),
    ('[[faults]]\nkind = "valve_closed"\nrope = 2\n[[faults]]\nkind = "valve_closed"\nrope = 2\nat_s = 5.0\n',
     "faults[1].rope", "already"),
    ('[[faults]]\nkind = "leak"\nrope = 3\n', "faults[0].rate_L_min", "missing"),
    ('[[faults]]\nkind = "leak"\nrope = 3\nrate_L_min = 0.0\n', "faults[0].rate_L_min", "> 0"),
    ('[[faults]]\nkind = "leak"\nrope = 3\nrate_L_min = "a lot"\n', "faults[0].rate_L_min", "must be a number"),
    ('[[faults]]\nkind = "leak"\nrope = -1\nrate_L_min = 0.1\n', "faults[0].rope", ">= 0"),
    ('[[faults]]\nkind = "seized_seal"\nrope = 1\n', "faults[0].factor", "missing"),
    ('[[faults]]\nkind = "seized_seal"\nrope = 1\nfactor = 0.5\n', "faults[0].factor", ">= 1"),
    ('[[faults]]\nkind = "creep"\nmm_per_wind = [1.0, 0.0]\n', "faults[0].mm_per_wind", "one value per rope"),
    ('[[faults]]\nkind = "creep"\nmm_per_wind = [80.0, 0.0, 0.0, 0.0]\n', "faults[0].mm_per_wind", "at most 50"),
    ('[[faults]]\nkind = "creep"\n', "faults[0].mm_per_wind", "missing"),
    ('[[faults]]\nkind = "creep"\nmm_per_wind = 1.0\n[[faults]]\nkind = "creep"\nmm_per_wind = 2.0\n',
     "faults[1].rope", "already"),
    ('faults = 3\n', "faults", "[[faults]] tables"),
    ('faults = [1]\n', "faults[0]", "must be a table"),
    ('[plant.end_stops]\nstiffness_N_m = -1.0\n', "plant.end_stops.stiffness_N_m", ">= 1"),
    ('[plant.end_stops]\ndamping_N_s_m = "soft"\n', "plant.end_stops.damping_N_s_m", "must be a number"),
    ('[plant.end_stops]\nstiffnes_N_m = 1e8\n', "plant.end_stops.stiffnes_N_m", "unknown field"),
])
def test_bad_fault_is_named(tmp_path, scenarios_dir, extra, field, reason):
    text = _field_trip_text(scenarios_dir)
    if extra.startswith("[plant.end_stops]"):
        text = text.replace("[plant.friction]", extra + "\n[plant.friction]", 1)
    elif extra.startswith("faults ="):
        text = extra + text
    else:
        text = text + "\n" + extra
    p = _write(tmp_path, scenarios_dir, text)
    with pytest.raises(ScenarioError) as e:
        load_scenario(p)
    msg = str(e.value)
    assert msg.startswith(field + ":"), msg
    assert reason in msg, msg


def test_creep_needs_a_hoist(tmp_path, scenarios_dir):
    text = (scenarios_dir / "paper-connection-device.toml").read_text()
    p = _write(tmp_path, scenarios_dir, text + '\n[[faults]]\nkind = "creep"\nmm_per_wind = 1.0\n')
    with pytest.raises(ScenarioError, match=r"^faults\[0\]\.kind: creep needs a hoist"):
        load_scenario(p)


def test_simulate_refuses_a_bad_fault_without_a_traceback(tmp_path, scenarios_dir):
    import subprocess
    import sys

    p = _write(tmp_path, scenarios_dir, _field_trip_text(scenarios_dir) + '\n[[faults]]\nkind = "leak"\nrope = 9\nrate_L_min = 1\n')
    r = subprocess.run([sys.executable, "-m", "ropemon.cli", "simulate", str(p), "--out", str(tmp_path / "o")],
                       capture_output=True, text=True)
    assert r.returncode == 1
    assert "faults[0].rope" in r.stderr and "Traceback" not in r.stderr
