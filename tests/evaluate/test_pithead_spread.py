"""`ropemon study pithead-spread`: the pithead total rerun on recombined seeds' inputs."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ropemon import cli
from ropemon.lab.studies import parse_set
from ropemon.lab.studies import pithead_spread as ps
from ropemon.lab.studies.seed_spread import run_seed


def test_spliced_takes_the_donors_columns_over_the_rows_only():
    base = np.zeros((6, 4), np.uint16)
    donor = np.arange(24, dtype=np.uint16).reshape(6, 4)
    out = ps.spliced(base, donor, slice(0, 2), slice(2, 4))
    assert np.array_equal(out[2:4, 0:2], donor[2:4, 0:2])
    out[2:4, 0:2] = 0
    assert not out.any()  # nothing else taken
    assert not base.any()  # the base is not changed
    assert np.array_equal(ps.spliced(base, donor, slice(1, 2))[:, 1], donor[:, 1])


def test_set_parses_json_values_and_refuses_a_malformed_one():
    assert parse_set(["a=1,2.5", "b=true"]) == [("a", [1, 2.5]), ("b", [True])]
    for bad in ("a", "=1", "a=", "a=1,x"):
        with pytest.raises(SystemExit, match="--set"):
            parse_set([bad])


def test_summary_adds_the_seeds_within_over_the_scenarios():
    tallies = {"a": {"as evaluated": (7, 10, 0.26), "x0": (10, 10, 0.15)},
               "b": {"as evaluated": (6, 10, 0.34), "x0": (9, 10, 0.20)}}
    lines = ps.summary_table(tallies)
    assert lines[2] == "| experiment | within | a | b | rope RMS % (worst) |"
    assert lines[4] == "| as evaluated | 13 of 20 | 7 | 6 | 0.34 |"
    assert lines[5] == "| x0 | 19 of 20 | 10 | 9 | 0.20 |"


@pytest.fixture(scope="module")
def two_seeds(tmp_path_factory):
    """`ropemon study seed-spread`'s work directory for seeds 1 and 2 of the short wind."""
    out = tmp_path_factory.mktemp("spread")
    for seed in (1, 2):
        run_seed(seed, ["short-test"], out, quick=True)
    return out


def test_scaling_the_pressure_noise(two_seeds):
    w = ps.load(two_seeds, "short-test", 2)
    n = int(w.physical["ropes"])
    clean = ps.true_pressure_counts(w.physical, w.truth)
    noise = w.records[:, :n] - clean
    # x1 gives back the records and the measured noise; x0 the true pressure, rounded
    recs, ph = ps.scaled_pressure_noise(w, 1.0)
    assert np.array_equal(recs, w.records)
    assert math.isclose(ph["pressure_noise_Pa"], w.physical["pressure_noise_Pa"], rel_tol=1e-9)
    recs, ph = ps.scaled_pressure_noise(w, 0.0)
    assert np.abs(recs[:, :n] - clean).max() <= 0.5
    assert np.array_equal(recs[:, n:], w.records[:, n:])  # only the pressure channels change
    assert math.isclose(ph["pressure_noise_Pa"], ps.count_step_pa(w.physical) / math.sqrt(12))
    # x0.5: half the noise (plus the rounding to counts), measured on the records
    recs, _ = ps.scaled_pressure_noise(w, 0.5)
    ratio = (recs[:, :n] - clean).std() / noise.std()
    assert 0.48 < ratio < 0.56
    # a small change is not rounded away: x0.95 and x1.05 are that within 1 %
    for scale in (0.95, 1.05):
        recs, _ = ps.scaled_pressure_noise(w, scale)
        assert (recs[:, :n] - clean).std() / noise.std() == pytest.approx(scale, rel=0.01)
    # a pressure channel reading a loop fault (0 counts: 0 mA) is refused, not scaled
    w.records = w.records.copy()
    w.records[10, 0] = 0
    with pytest.raises(ValueError, match="pressure channel 1"):
        ps.scaled_pressure_noise(w, 0.5)


def table_rows(out: str):
    """The printed table's per-seed figures by experiment: rows(label) -> [seed 1 %, ...]."""
    rows = {line.split("|")[1].strip(): line for line in out.splitlines() if line.startswith("| ")}
    return lambda label: [float(v) for v in rows[label].rstrip(" |").split("|")[-1].split(",")]


def test_table_reproduces_the_evaluation_and_its_controls(two_seeds, capsys):
    assert cli.main(["study", "pithead-spread", str(two_seeds), "short-test", "--scale", "0",
                     "--set", "friction_play_sigmas=1.45,2"]) == 0
    out = capsys.readouterr().out
    per_seed = table_rows(out)

    # as evaluated: each seed's figure as `ropemon evaluate` printed it (2 decimals)
    want = [json.loads((two_seeds / f"seed-{s}" / "results.json").read_text())
            ["scenarios"]["short-test"]["estimators"]["lugre-p+loss"]["pithead_total_pct"] for s in (1, 2)]
    got = per_seed("as evaluated")
    assert got == pytest.approx(want, abs=0.006)
    # seed 1 with its own config, its own pressure and its own displacement: the same run
    for label in ("seed-1 config", "pressure noise only", "displacement noise only"):
        assert per_seed(label)[0] == got[0], label
    # seed 2 takes seed 1's config, or gives seed 1 its noise: other runs
    assert per_seed("pressure noise only")[1] != got[1]
    # the default play's row is the evaluation; a play of 2 sigma is another
    assert per_seed("friction_play_sigmas=1.45") == got
    assert per_seed("friction_play_sigmas=2") != got
    assert "pressure noise x0 " in out
    assert "(basis: arrival rest)" in out  # the short wind ends loaded
    # seed 2's pressure noise in seed 1's wind, one stretch at a time
    assert "Seed 2's pressure noise in seed 1's wind" in out
    stretches = [line for line in out.splitlines() if line.startswith(("| until", "| the ", "| then"))]
    assert stretches and all(len(line.split("|")) == 7 for line in stretches)


def test_drift_keeps_the_commissioned_config_and_the_grid_runs_at_each_scale_and_drift(two_seeds, capsys):
    assert cli.main(["study", "pithead-spread", str(two_seeds), "short-test", "--scale", "0.5", "--drift", "1,0.5",
                     "--set", "friction_play_sigmas=1.45,2"]) == 0
    per_seed = table_rows(capsys.readouterr().out)
    # the noise as commissioned is the evaluation itself
    assert per_seed("pressure noise x1 after commissioning") == per_seed("as evaluated")
    # half the noise with the config as commissioned (a play twice the noise's) is not
    # half the noise commissioned with it
    assert per_seed("pressure noise x0.5 after commissioning") != per_seed("pressure noise x0.5")
    # the grid at x0.5: the default play is that row, another play another run
    assert per_seed("pressure noise x0.5, friction_play_sigmas=1.45") == per_seed("pressure noise x0.5")
    assert per_seed("pressure noise x0.5, friction_play_sigmas=2") != per_seed("pressure noise x0.5")
    assert per_seed("friction_play_sigmas=1.45") == per_seed("as evaluated")
    # and after commissioning: the default play is the drift row, another play another run
    drift = "pressure noise x0.5 after commissioning"
    assert per_seed(f"{drift}, friction_play_sigmas=1.45") == per_seed(drift)
    assert per_seed(f"{drift}, friction_play_sigmas=2") != per_seed(drift)


def test_a_setting_the_config_refuses_is_named(two_seeds):
    with pytest.raises(SystemExit, match="--set friction_play_sigmas=9: physical.rest_play_sigmas"):
        cli.main(["study", "pithead-spread", str(two_seeds), "short-test", "--scale", "",
                  "--set", "friction_play_sigmas=9"])


def test_the_smoother_follows_its_model_with_less_noise_than_the_tracker(two_seeds):
    physical = ps.load(two_seeds, "short-test", 1).physical
    smoother = ps.Smoother(physical)
    # its model's own signals pass unchanged: a constant pressure, and a creep at a
    # constant rate once the start (no rate yet) is behind
    assert np.array_equal(smoother.run(np.full(400, 3e6)), np.full(400, 3e6))
    t = np.arange(4000) / 200.0
    ramp = 1e6 + 2e3 * t
    assert np.abs(smoother.run(ramp) - ramp)[400:].max() < 1e-3
    # the noise gain from its impulse response is what white noise shows, and below the
    # tracker's (it reads each sample with the wind after it as well as before)
    gain = smoother.noise_gain(200.0)
    noise = np.random.default_rng(1).standard_normal(40000)
    assert np.std(smoother.run(noise)[2000:-2000]) == pytest.approx(gain, rel=0.05)
    assert gain < 0.8 * smoother.tracker_noise_gain


def test_the_smoother_row_replays_its_estimate_into_the_reference(two_seeds, capsys, monkeypatch):
    # the tracker itself put in the smoother's place must give back the evaluation's
    # figures: the medians, the replay and the play scaling are right (said to be half
    # as noisy as the tracker, its plays x2 are the tracker's own)
    from ropemon.commission import nodejson, reference

    class TrackerAsSmoother:
        def __init__(self, physical):
            self.tr = nodejson.physical_params(physical)["tracker"]
            self.tracker_noise_gain = self.tr["noise_gain"]

        def run(self, y):
            tracker = reference.PressureTracker(self.tr)
            return np.array([tracker.step(float(v)) for v in y])

        def noise_gain(self, fs):
            return 0.5 * self.tracker_noise_gain

    argv = [str(two_seeds), "short-test", "--scale", "", "--smoother", "2,1"]

    def rows():
        assert cli.main(["study", "pithead-spread", *argv]) == 0
        out = capsys.readouterr().out
        return {line.split("|")[1].strip(): line.rstrip(" |").split("|")[-1] for line in out.splitlines()
                if line.startswith("| ")}

    real = rows()
    monkeypatch.setattr(ps, "Smoother", TrackerAsSmoother)
    stand_in = rows()
    assert stand_in["smoother, plays x2"] == stand_in["as evaluated"] == real["as evaluated"]
    assert stand_in["smoother, plays x1"] != stand_in["as evaluated"]  # the plays do scale
    assert real["smoother, plays x2"] != real["as evaluated"]  # and the smoother is another estimate
    # and across a stretch where no pressure channel is healthy (each stretch with a
    # median is smoothed on its own, as the tracker starts afresh after it), the replay
    # still gives back the tracker's own figure
    w = ps.load(two_seeds, "short-test", 1)
    n = int(w.physical["ropes"])
    recs = w.records.copy()
    recs[1000:1100, :n] = 0  # 0 mA on every pressure loop for 0.5 s
    assert ps.smoothed_score(w.physical, recs, w, 2.0) == ps.score(w.physical, recs, w)
