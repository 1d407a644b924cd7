"""The error computation checked on cases small enough to work out by hand."""
import math

import numpy as np
import pytest

from ropemon.lab import metrics as m

RATED = 1000.0  # N: 1 N of error is 0.1 % of rated


def test_rms_and_peak_per_rope_and_total_by_hand():
    truth = np.full((4, 2), 500.0)
    est = truth.copy()
    est[:, 0] += [10.0, -10.0, 10.0, -10.0]  # rope 0: RMS 10 N = 1 %, peak 1 %
    est[:, 1] += [0.0, 0.0, 0.0, 30.0]       # rope 1: RMS sqrt(900/4) = 15 N = 1.5 %, peak 3 %
    f = m.error_figures(est, truth, RATED, np.ones(4, bool))
    assert f["per_rope_rms_pct"] == pytest.approx([1.0, 1.5])
    assert f["per_rope_peak_pct"] == pytest.approx([1.0, 3.0])
    assert f["rope_rms_pct"] == pytest.approx(1.5)
    assert f["rope_peak_pct"] == pytest.approx(3.0)
    # total errors 10, -10, 10, 20 N of a rated total of 2000 N
    assert f["total_rms_pct"] == pytest.approx(math.sqrt((100 + 100 + 100 + 400) / 4) / 2000 * 100)
    assert f["total_peak_pct"] == pytest.approx(1.0)


def test_excluded_samples_do_not_count():
    truth = np.full((3, 1), 500.0)
    est = truth + np.array([[0.0], [100.0], [0.0]])
    keep = np.array([True, False, True])
    f = m.error_figures(est, truth, RATED, keep)
    assert f["samples"] == 2 and f["rope_peak_pct"] == 0.0
    assert m.error_figures(est, truth, RATED, np.ones(3, bool))["rope_peak_pct"] == pytest.approx(10.0)


def test_shock_mask_holds_half_a_second():
    t = np.arange(0, 2.0, 0.1)
    ex = m.shock_mask(t, [0.5])
    assert list(np.round(t[ex], 1)) == [0.5, 0.6, 0.7, 0.8, 0.9]


def test_detect_shocks_finds_onset_of_a_step_only():
    t = np.arange(10) * 0.01
    tension = np.full((10, 2), 100.0)
    tension[5:, 1] = 200.0  # +100 N in 10 ms = 10000 N/s, rated 1000 N: well above 0.5/s
    tension[:, 0] += np.arange(10) * 0.1  # slow drift, 10 N/s: not a shock
    assert list(m.detect_shocks(t, tension, RATED)) == pytest.approx([0.05])


def test_phases_from_cage_motion():
    depth = np.array([0.0, 1.0, 100.0, 400.0, 700.0, 809.0, 810.0, 810.0])
    speed = np.array([0.0, 0.3, 5.0, 10.0, 5.0, 0.3, 0.0, -0.3])
    accel = np.array([0.0, 0.5, 0.7, 0.0, -0.7, -0.5, 0.0, -0.5])
    got = [m.PHASES[k] for k in m.classify_phases(depth, speed, accel, 810.0)]
    assert got == ["rest-pithead", "reversal-creep", "acceleration", "constant-speed",
                   "deceleration", "reversal-creep", "rest-bottom", "reversal-creep"]


def test_deceleration_going_up_is_deceleration():
    # going up (u < 0) and braking (a > 0)
    ph = m.classify_phases(np.array([400.0]), np.array([-8.0]), np.array([0.7]), 810.0)
    assert m.PHASES[ph[0]] == "deceleration"


def test_pithead_total_uses_the_rest_after_arrival():
    phase = np.array([m.REST_PITHEAD, m.REST_PITHEAD, m.CONSTANT_SPEED, m.REST_PITHEAD, m.REST_PITHEAD])
    truth = np.full((5, 2), 100.0)
    est = truth.copy()
    est[:2] -= 50.0          # before the wind: ignored
    est[3:] -= [1.0, 1.0]    # after arrival: sum 198 vs 200 -> -1 %
    assert m.pithead_total_pct(est, truth, phase, np.zeros(5, bool)) == pytest.approx(-1.0)


def test_by_phase_split():
    phase = np.array([m.ACCELERATION, m.ACCELERATION, m.DECELERATION])
    truth = np.full((3, 1), 100.0)
    est = truth + np.array([[2.0], [-2.0], [5.0]])
    f = m.evaluate_estimate(est, truth, RATED, phase, np.zeros(3, bool))
    assert f["by_phase"]["acceleration"]["rope_rms_pct"] == pytest.approx(0.2)
    assert f["by_phase"]["deceleration"]["rope_peak_pct"] == pytest.approx(0.5)
    assert f["by_phase"]["rest-bottom"]["samples"] == 0


def test_deviation_step_gives_exact_deviation():
    rng = np.random.default_rng(1)
    truth = 1000.0 + rng.normal(0, 5, (50, 4))
    for dev in (0.08, -0.12):
        t = truth.copy()
        t[:, 2] += m.deviation_step_n(truth, 2, dev)
        assert m.deviation_from_mean(t)[:, 2] == pytest.approx(np.full(50, dev))


def test_alarm_assessment_perfect_estimate_has_no_false_or_missed():
    truth = np.full((40, 4), 1000.0)
    a = m.alarm_assessment(truth, truth, np.zeros(40, bool), window=4)
    assert a["8"] == {"frames": 80, "false": 0, "missed": 0, "detected_frac": 0.0}
    assert a["12"]["missed"] == 0 and a["12"]["false"] == 0 and a["12"]["detected_frac"] == 1.0


def test_alarm_assessment_counts_errors_of_a_biased_estimate():
    truth = np.full((40, 4), 1000.0)
    est = truth.copy()
    est[:, 0] += 30.0  # rope 0 reads 3 % high: 8 % + 3 % > 10 % on rope 0 when it deviates up
    a = m.alarm_assessment(est, truth, np.zeros(40, bool), window=4)
    # 10 frames per case; 4 ropes x 2 signs = 8 cases, 80 frames. At +8 % on rope 0 the
    # estimate reads ~+10.6 %: 10 false frames. Others: rope 0 alone at ~+3 %, fine.
    assert a["8"]["false"] == 10 and a["8"]["missed"] == 0
    # at -12 % on rope 0 it reads ~ -9.6 %: missed in all 10 frames
    assert a["12"]["missed"] == 10 and a["12"]["false"] == 0


def test_alarm_assessment_skips_shock_windows():
    truth = np.full((40, 4), 1000.0)
    est = truth.copy()
    est[:, 0] += 30.0
    excluded = np.zeros(40, bool)
    excluded[:20] = True     # the first 5 frames
    excluded[21] = True      # one sample of frame 5
    a = m.alarm_assessment(est, truth, excluded, window=4)
    assert a["8"]["frames"] == 8 * 4 and a["8"]["false"] == 4


def test_missing_tension_is_left_out_and_counted():
    truth = np.full((4, 2), 500.0)
    est = truth + [[1.0, 2.0]]
    est[1, 0] = np.nan
    f = m.error_figures(est, truth, RATED, np.ones(4, bool))
    assert f["no_tension_samples"] == 1
    assert f["per_rope_rms_pct"] == pytest.approx([0.1, 0.2])
    assert f["total_peak_pct"] == pytest.approx(3.0 / 2000 * 100)  # of 2 x rated
    a = m.alarm_assessment(est, truth, np.zeros(4, bool), window=2)
    assert a["8"]["frames"] == 2 * 2  # 1 of 2 windows has a rope without tension: 2 ropes x 2 signs


def test_pithead_total_leaves_out_loading():
    phase = np.array([m.CONSTANT_SPEED] + [m.REST_PITHEAD] * 4)
    truth = np.full((5, 1), 100.0)
    est = truth - [[0.0], [2.0], [50.0], [50.0], [2.0]]
    steady = np.array([True, True, False, False, True])  # samples 2, 3: payload being changed
    assert m.pithead_total_pct(est, truth, phase, np.zeros(5, bool), steady) == pytest.approx(-2.0)


def test_pithead_figures_split_the_loaded_arrival_from_the_empty_cage():
    """The field trip's pithead: loaded rest as arrived, unloading, rest empty (the paper's figure)."""
    phase = np.array([m.CONSTANT_SPEED] + [m.REST_PITHEAD] * 7)
    payload = np.array([3000.0, 3000.0, 3000.0, 1500.0, 0.0, 0.0, 0.0, 0.0])
    steady = np.concatenate([[True], np.diff(payload) == 0])   # samples 3, 4: unloading
    excluded = np.zeros(8, bool)
    excluded[5] = True                                          # a shock window right after unloading
    truth = np.full((8, 2), 100.0)
    est = truth - [[0, 0], [4, 0], [4, 0], [50, 50], [50, 50], [90, 90], [1, 0], [1, 0]]
    f = m.pithead_figures(est, truth, phase, excluded, steady, payload)
    assert f["pithead_arrival_total_pct"] == pytest.approx(-2.0)   # samples 1, 2: 196 of 200
    assert f["pithead_empty_total_pct"] == pytest.approx(-0.5)     # samples 6, 7: 199 of 200
    assert f["pithead_total_pct"] == f["pithead_empty_total_pct"] and f["pithead_total_basis"] == "empty"
    # a scenario whose cage stays loaded at the pithead: the arrival rest, and it says so
    loaded = m.pithead_figures(est, truth, phase, excluded, steady, np.full(8, 3000.0))
    assert math.isnan(loaded["pithead_empty_total_pct"])
    assert loaded["pithead_total_basis"] == "arrival"
    # the whole steady rest after arrival (no payload change seen): samples 1, 2, 6, 7
    assert loaded["pithead_total_pct"] == pytest.approx(-10.0 / 800 * 100)


def test_pithead_figures_of_a_cage_arriving_empty_count_the_whole_rest_as_empty():
    phase = np.array([m.CONSTANT_SPEED] + [m.REST_PITHEAD] * 3)
    truth = np.full((4, 1), 200.0)
    est = truth - [[9.0], [1.0], [1.0], [1.0]]
    f = m.pithead_figures(est, truth, phase, np.zeros(4, bool), None, np.zeros(4))
    assert f["pithead_empty_total_pct"] == f["pithead_arrival_total_pct"] == pytest.approx(-0.5)


def test_operator_alarms_use_the_hosts_debounce():
    """With frame_s the assessment also runs the host's debounce: 10 frames of 0.1 s."""
    truth = np.full((40, 4), 1000.0)
    est = truth.copy()
    est[:, 0] += 30.0  # as above: at +8 % rope 0 reads ~+10.6 % in all 10 frames
    a = m.alarm_assessment(est, truth, np.zeros(40, bool), window=4, frame_s=0.1)
    # one raise, 0.5 s in; no other case raises
    assert a["8"]["false"] == 10 and a["8"]["false_alarms"] == 1
    # at -12 % rope 0 reads ~ -9.6 %, never flagged; the debounce on the truth holds the
    # alarm from frame 5 (0.5 s): 5 missed alarm frames, the debounce's delay not counted
    assert a["12"]["missed"] == 10 and a["12"]["missed_alarm_frames"] == 5
    assert a["12"]["false_alarms"] == 0 and a["8"]["missed_alarm_frames"] == 0


def test_a_short_error_is_a_false_frame_but_no_operator_alarm():
    truth = np.full((40, 4), 1000.0)
    est = truth.copy()
    est[8:24, 0] += 30.0  # frames 2-5 (0.3 s of condition) read ~+10.6 % at +8 %
    a = m.alarm_assessment(est, truth, np.zeros(40, bool), window=4, frame_s=0.1)
    assert a["8"]["false"] == 4 and a["8"]["false_alarms"] == 0


def test_a_shock_window_restarts_the_debounce():
    truth = np.full((40, 4), 1000.0)
    est = truth.copy()
    est[:, 0] += 30.0
    excluded = np.zeros(40, bool)
    excluded[17] = True  # frame 4 skipped: frames 0-3 and 5-9, 0.3 and 0.4 s of condition
    a = m.alarm_assessment(est, truth, excluded, window=4, frame_s=0.1)
    assert a["8"]["false"] == 9 and a["8"]["false_alarms"] == 0
    # the truth's alarm at -12 % never holds either: no frame counts as a missed alarm
    assert a["12"]["missed_alarm_frames"] == 0
