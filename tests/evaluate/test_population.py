"""The population of drawn hoists: reproducible draws, and the silent / false-warning scoring."""
from __future__ import annotations

import numpy as np
import pytest

from ropemon.lab import population as P
from ropemon.station.alarms import AlarmEngine, AlarmSettings
from ropemon.station.protocol import decode_raw, encode_frame

FRAME_S = 0.1
AREA = 7.854e-3


def frames_from(tensions_n: np.ndarray, raw_kpa: np.ndarray | None = None):
    """Decoded frames whose rope means are the given tensions (N); raw pressure as given or p = T/A."""
    out = []
    for k, row in enumerate(tensions_n):
        ropes = []
        for i, t in enumerate(row):
            dan = int(round(t / 10))
            kpa = int(round((t if raw_kpa is None else raw_kpa[k, i]) / AREA / 1000))
            ropes.append((dan, dan, dan, kpa))
        raw, _ = encode_frame(node=1, seq=k, time_ms=int(k * FRAME_S * 1000), ropes=ropes, battery_mv=4000)
        out.append(decode_raw(raw))
    return out


def baseline():
    return AlarmEngine(AlarmSettings(stuck_s=None))


def test_the_draw_is_seeded_and_reproducible():
    a, b = P.draw(101), P.draw(101)
    assert a == b
    c = P.draw(102)
    assert a != c
    for seed in (1, 20, 101, 200):
        h = P.draw(seed)
        assert h.law in P.LAWS
        assert all(abs(o) <= 0.010 for o in h.offsets_m)
        assert 0.090 <= h.bore_m <= 0.125
        assert 0.0 <= h.oil_temp_C <= 40.0 and 0.0 <= h.payload_kg <= 12000.0
        assert len(h.friction["force_scale"]) == P.ROPES


def test_tuning_and_scoring_seeds_do_not_overlap():
    assert not set(P.TUNING_SEEDS) & set(P.SCORING_SEEDS)
    assert len(P.SCORING_SEEDS) == 100


def test_the_draws_cover_every_law():
    laws = {P.draw(s).law for s in P.SCORING_SEEDS}
    assert laws == set(P.LAWS)


def test_population_names_round_trip():
    assert P.seed_of("population-137") == 137
    assert P.seed_of("population-x") is None and P.seed_of("paper-field-trip") is None


def test_site_change_sets_bore_and_scales_each_ropes_hoses():
    from ropemon.lab.evaluate import SCENARIO_DIR

    h = P.draw(103)
    text = (SCENARIO_DIR / "paper-site.toml").read_text()
    import tomllib

    before, after = tomllib.loads(text), tomllib.loads(P.change_site(h)(text))
    assert after["cylinders"]["bore_m"] == h.bore_m
    for i in range(P.ROPES):
        for s0, s1 in zip(before["pipes"][i]["segments"], after["pipes"][i]["segments"]):
            assert s1["length_m"] == pytest.approx(s0["length_m"] * h.hose_scale[i], abs=1e-3)
    with pytest.raises(ValueError, match="bore_m"):
        P.change_site(h)(text.replace("bore_m = 0.100", "# no bore"))


def wind(dev_rope2: np.ndarray, mean_n: float = 50e3) -> np.ndarray:
    """Four ropes at mean_n whose rope 2 deviates by dev_rope2 (fractions, per frame) from their mean."""
    n = len(dev_rope2)
    t = np.full((n, 4), mean_n)
    # rope 2 at (1 + d) m, the others share the rest so the mean stays m
    t[:, 1] = mean_n * (1 + dev_rope2)
    t[:, [0, 2, 3]] = ((4 * mean_n - t[:, 1]) / 3)[:, None]
    return t


def test_a_true_deviation_the_node_does_not_see_is_a_silent_episode():
    dev = np.zeros(200)
    dev[50:100] = 0.12            # 5 s beyond the limit
    truth = wind(dev)
    shown = wind(np.where(dev > 0, 0.06, 0.0))   # the node shows 6 %
    fig = P.alarm_figures(frames_from(shown), truth, FRAME_S, baseline)
    assert fig["episodes"] == 1
    assert fig["silent"] and fig["silent"][0]["rope"] == 2
    assert fig["silent"][0]["true_max_pct"] == pytest.approx(12.0, abs=0.01)


def test_a_seen_deviation_is_not_silent_and_a_short_one_is_not_an_episode():
    dev = np.zeros(200)
    dev[50:100] = 0.12
    dev[150:165] = 0.12           # 1.5 s: shorter than SILENT_MIN_S
    truth = wind(dev)
    fig = P.alarm_figures(frames_from(truth), truth, FRAME_S, baseline)
    assert fig["episodes"] == 1 and fig["silent"] == []


def test_an_alarm_on_a_rope_truly_within_8_percent_is_a_false_warning():
    truth = wind(np.full(100, 0.05))
    shown = wind(np.full(100, 0.11))
    fig = P.alarm_figures(frames_from(shown), truth, FRAME_S, baseline)
    assert fig["false_warnings"] >= 1 and fig["episodes"] == 0
    # rope 2's alarm stands from 0.5 s on (debounce) through 10 s: ~95 % of one rope in four
    assert fig["warning_share"] == pytest.approx(0.25 * 0.95, abs=0.01)
    fig = P.alarm_figures(frames_from(truth), truth, FRAME_S, baseline)
    assert fig["false_warnings"] == 0 and fig["warning_share"] == 0.0


def test_superposed_deviation_moves_tension_and_pressure_together():
    truth = wind(np.zeros(60))
    frames = frames_from(truth)
    step = np.full(60, 6000.0)
    out = P.superposed_frames(frames, 2, step, AREA)
    for f0, f1 in zip(frames, out):
        assert f1.ropes[2].mean_dan - f0.ropes[2].mean_dan == 600
        assert f1.ropes[2].raw_kpa - f0.ropes[2].raw_kpa == round(6000 / AREA / 1000)
        assert f1.ropes[0] == f0.ropes[0]
    # an exact node: every superposed 12 % is seen, none is silent, and nothing is false
    fig = P.superposed_alarm_figures(frames, truth, FRAME_S, baseline, AREA)
    assert fig["cases"] == 8 and fig["episodes"] == 8
    assert fig["silent"] == [] and fig["false_warnings"] == 0


def test_quantiles_ignore_missing_values():
    q = P.quantiles([1.0, None, float("nan"), 3.0, 2.0])
    assert q == {"median": 2.0, "p95": pytest.approx(2.9), "n": 3}
    assert P.quantiles([None])["median"] is None


def test_one_drawn_wind_end_to_end_and_the_json_summary(tmp_path):
    """A drawn hoist simulated, commissioned (quick bed), run through the firmware under
    micropython and scored; the summary has the fields `ropemon evaluate --population --json` prints."""
    from ropemon.lab.evaluate import BED_QUICK, FIRMWARE

    r = P.run_wind(1, tmp_path, firmware=True, bed=BED_QUICK)
    assert "error" not in r, r.get("error")
    assert r["law"] == P.draw(1).law
    fw = r["estimators"][FIRMWARE]
    assert 0 < fw["rope_rms_pct"] < 50 and fw["pithead_total_pct"] is not None
    assert r["firmware_vs_float_max_pct"] is not None
    # the same against the reference following the node's stroke decisions: none disputed
    fo = r["firmware_vs_float_following"]
    assert "error" not in fo, fo
    assert fo["disputes"] == 0 and 0.0 <= fo["max_pct"] <= 0.05, fo
    # the baseline node (slide following off) ran its own firmware: its own frames and reference
    assert r["estimators"][P.BASELINE_FIRMWARE]["rope_rms_pct"] > 0
    assert r["baseline_firmware_vs_float_max_pct"] is not None
    assert (tmp_path / P.draw(1).name / "frames-baseline.bin").exists()
    for which in ("baseline", "node"):
        al = r["alarms"][which]
        assert al["superposed"]["cases"] == 8 and al["superposed"]["episodes"] >= 8
    s = P.summary([r], "node")
    for key in ("rope_rms_pct", "rope_peak_pct", "pithead_total_abs_pct"):
        assert set(s[key]) >= {"median", "p95"}
    assert s["winds"] == 1 and isinstance(s["silent_winds"], int)
    assert s["false_warnings_per_wind"] is not None and s["firmware_vs_float_max_pct"] is not None
    assert s["following"]["disputes"] == 0 and s["following"]["max_pct"] == round(fo["max_pct"], 4)
    assert 0.0 <= r["ideal_bound"]["warning_share"] <= 1.0
    # re-scoring the run directory decodes both runs' frames (they share their sequence numbers)
    again = P.rescore_wind(tmp_path / P.draw(1).name)
    assert again["node"]["natural"] == r["alarms"]["node"]["natural"]
    assert again["baseline"]["natural"] == r["alarms"]["baseline"]["natural"]
    md = P.markdown({"population": s, "baseline": P.summary([r], "baseline"),
                                             "by_law": P.by_law([r]), "seeds": "tuning", "wall_s": 1.0,
                                             "winds": [r]})
    assert "| silent winds |" in md and "decisions followed on" in md


def ideal_case(load_n: float):
    """Four ropes at 5 MPa on equal areas, seals Fs = 2 kN, Fc = 1.5 kN (flat), sigma0 = 1e8 N/m
    (pre-sliding 20 um); 40 samples at 10 Hz, a frame each; every piston slides up 0.1 mm at
    sample 20 and the seals then hold 1.8 kN."""
    n, ropes = 40, 4
    area = load_n / 5e6
    x = np.zeros((n, ropes))
    x[20:, :] = 1e-4
    f = np.zeros((n, ropes))
    f[20:, :] = 1800.0
    physical = {"cylinder_area_m2": [area] * ropes, "ropes": ropes, "sample_hz": 10, "frame_hz": 10,
                "friction": {"Fs": {"intercept": 2000.0, "slope": 0.0}, "Fc": {"intercept": 1500.0, "slope": 0.0},
                             "sigma0": 1e8, "residual": 0.0}}
    truth = {"piston_x_m": x, "p_tap_Pa": np.full((n, ropes), 5e6), "friction_N": f,
             "tension_N": np.full((n, ropes), load_n)}
    return truth, physical


def test_the_ideal_bound_keeps_the_seals_range_until_the_pistons_slide_and_then_narrows():
    """Hand-checked, S = 1.1 x 2 kN = 2.2 kN, L = 0.9 x 1.5 kN = 1.35 kN. At rest the intervals are
    [-S, S]; once the pistons slid (0.1 mm, beyond (S + L) / k_min = 53 um) [L, S]. On 40 kN ropes:
    d_max = 4 x 42.2 / (42.2 + 3 x 37.8) - 1 = 8.5 % at rest, 4 x 42.2 / (42.2 + 3 x 41.35) - 1 =
    1.5 % slid: never a warning. On 20 kN ropes 17.5 % at rest (a warning), 3.0 % slid: half the time."""
    truth, physical = ideal_case(40e3)
    fig = P.ideal_bound_figures(truth, physical, margin=0.10)
    assert fig["warning_share"] == 0.0 and fig["missed_frames"] == 0
    assert 0.0 < fig["superposed_warning_share"] <= 1.0 and fig["superposed_missed_frames"] == 0
    assert fig["coverage_min"] == 1.0
    truth, physical = ideal_case(20e3)
    fig = P.ideal_bound_figures(truth, physical, margin=0.10)
    assert fig["warning_share"] == 0.5 and fig["missed_frames"] == 0
    # a seal holding no force after it slid is outside [L, S]: the bound would not be fail-safe
    truth["friction_N"][20:, :] = 0.0
    assert P.ideal_bound_figures(truth, physical, margin=0.10)["coverage_min"] == 0.5


def test_a_drawn_stroke_fault_end_to_end_alarmed_on_its_rope_in_time(tmp_path):
    """Tuning seed 12: its drawn fault puts rope 1's piston 3.1 mm into its extended margin at its
    closest (by offsets); the faulted wind is simulated, the node run on it as commissioned, and
    the station's events scored: the truth has the piston in its margin, the station raises its
    stroke limit on rope 1 within 1 s; the legacy station raises none. The healthy wind is scored too."""
    from ropemon.lab.evaluate import BED_QUICK

    f = P.draw_fault(12)
    assert f.kind == "stroke_offset" and f.rope == 1 and f.params["end"] == "extended"
    r = P.run_wind(12, tmp_path, firmware=True, bed=BED_QUICK, faults=True)
    assert "error" not in r, r.get("error")
    t = r["targets"]
    assert t["legacy_distinct"] and t["healthy"]["hidden_known"]
    for which in P.CONFIGS:
        h = t["healthy"][which]["healthy"]
        assert isinstance(h["raised"], int) and isinstance(h["standing"], list)
    fa = t["fault"]
    assert "error" not in fa, fa.get("error")
    assert fa["truth"]["crossed"] and fa["truth"]["rope"] == 0, fa["truth"]
    st = fa["station"]["fault"]
    assert st["alarmed"] and st["in_time"] and st["latency_s"] <= P.STROKE_DEADLINE_S, st
    assert "stroke_limit" not in fa["legacy"]["fault"]["raised"]
    assert (tmp_path / P.draw(12).name / "fault" / "frames.bin").exists()
    # scored again from the stored frames and truth (`--rescore`): the same figures
    again = P.rescore_targets(12, tmp_path)
    assert again["targets"]["fault"]["station"] == fa["station"]
    assert again["targets"]["healthy"]["legacy"] == t["healthy"]["legacy"]
    s = P.targets_summary([r])
    assert s["station"]["classes"]["stroke_offset"]["in_time"] == 1
    md = P.targets_markdown({"targets": s, "seeds": "tuning", "wall_s": 1.0, "winds": [r]}, "ropemon evaluate x")
    assert md.startswith("Made by `ropemon evaluate x`") and "| stroke offset | 1 | 1 | 1 (1) |" in md
