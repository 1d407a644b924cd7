"""A site file and a scenario refuse the same fault in the same words (ropemon.station.tomlfields)."""
import shutil
from pathlib import Path

import pytest

from ropemon.station import tomlfields
from ropemon.lab.plant import scenario
from ropemon.commission.site import SiteError, _Table, load_site

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"


class _Err(ValueError):
    pass


@pytest.mark.parametrize("kind,value,bounds,message", [
    ("number", "810", {}, "must be a number, got '810'"),
    ("number", True, {}, "must be a number, got True"),
    ("number", float("nan"), {}, "must be finite, got nan"),
    ("number", 0, {"gt": 0}, "must be > 0, got 0"),
    ("number", -1.5, {"ge": 0}, "must be >= 0, got -1.5"),
    ("number", 1, {"lt": 1}, "must be < 1, got 1"),
    ("number", 26, {"le": 25}, "must be <= 25, got 26"),
    ("integer", 4.0, {}, "must be an integer, got 4.0"),
    ("integer", False, {}, "must be an integer, got False"),
    ("integer", 0, {"lo": 1}, "must be >= 1, got 0"),
    ("integer", 5, {"lo": 1, "hi": 4}, "must be <= 4, got 5"),
    ("string", 3, {}, "must be a string, got 3"),
    ("string", "crane", {"choices": ("hoist", "bench")}, "must be one of hoist, bench, got 'crane'"),
])
def test_site_and_scenario_refuse_alike(kind, value, bounds, message):
    with pytest.raises(SiteError) as site_err:
        getattr(_Table({"x": value}, "hoist"), kind)("x", **bounds)
    with pytest.raises(scenario.ScenarioError) as scen_err:
        getattr(scenario, kind)({"x": value}, "x", "hoist", **bounds)
    assert str(site_err.value) == str(scen_err.value) == f"hoist.x: {message}"


def test_accepted_values_pass_through():
    assert tomlfields.check_number(3, "x", _Err, gt=0, le=3) == 3.0
    assert isinstance(tomlfields.check_number(3, "x", _Err), float)
    assert tomlfields.check_int(4, "n", _Err, lo=1, hi=4) == 4


def test_load_names_the_file_and_raises_the_callers_error(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [unclosed")
    with pytest.raises(_Err, match=r"bad\.toml: not valid TOML"):
        tomlfields.load(bad, _Err)
    with pytest.raises(_Err, match=r"nope\.toml: cannot read"):
        tomlfields.load(tmp_path / "nope.toml", _Err)
    good = tmp_path / "good.toml"
    good.write_text("a = 1\n[b]\nc = 'x'\n")
    assert tomlfields.load(good, _Err) == {"a": 1, "b": {"c": "x"}}


def test_an_unknown_table_is_refused_by_the_site_and_by_the_scenario(tmp_path):
    """A misspelt table is not ignored: its settings would silently fall back to defaults."""
    for f in ("paper-site.toml", "paper-friction.json", "paper-compliance.json", "paper-field-trip.toml"):
        shutil.copy(SCENARIOS / f, tmp_path / f)
    site, trip = tmp_path / "paper-site.toml", tmp_path / "paper-field-trip.toml"
    good = site.read_text()
    site.write_text(good.replace("[compliance]", "[compliances]"))
    with pytest.raises(SiteError, match=r"^compliances: unknown field$"):
        load_site(site)
    with pytest.raises(scenario.ScenarioError, match=r"^site \(paper-site.toml\): compliances: unknown field$"):
        scenario.load_scenario(trip)
    site.write_text(good)
    trip.write_text(trip.read_text() + "\n[sensor]\npressure_noise_Pa = 1.0\n")
    with pytest.raises(scenario.ScenarioError, match=r"^sensor: unknown field$"):
        scenario.load_scenario(trip)


def test_pairs_are_read_alike():
    t = tomlfields.Table({"r": [1, 0]}, "sensors.pressure", _Err)
    with pytest.raises(_Err, match=r"^sensors.pressure.r: high must be > low, got \[1, 0\]$"):
        t.pair("r")
    assert tomlfields.pair({"r": [2, 2]}, "r", "duty", _Err, equal_ok=True) == (2.0, 2.0)
    with pytest.raises(_Err, match=r"^duty.r: must be \[low, high\], got 3$"):
        tomlfields.pair({"r": 3}, "r", "duty", _Err)
