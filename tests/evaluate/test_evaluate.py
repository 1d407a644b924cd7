"""Scoring, Markdown and plots of `ropemon evaluate` on a hand-made case."""
import json

import numpy as np
import pytest

from ropemon.lab import evaluate as ev
from ropemon.lab import metrics as m

RATED = 10000.0


def make_case():
    n = 400  # 2 s at 200 Hz, frames of 20 samples
    truth = np.full((n, 2), 5000.0)
    phase = np.full(n, m.CONSTANT_SPEED, np.int8)
    phase[:100] = m.REST_PITHEAD
    phase[300:] = m.REST_PITHEAD
    excluded = np.zeros(n, bool)
    excluded[100:140] = True
    full = truth + 10.0            # 0.1 % of rated high everywhere
    raw = truth - 1000.0           # 10 % low
    fw = m.window_means(full, 20) + 1.0   # 1 N off the float reference
    case = ev.Case(name="hand", sample_hz=200, frame_hz=10, rated_n=RATED, truth_n=truth,
                   phase=phase, excluded=excluded,
                   estimates={"raw": raw, "lugre-p+loss": full}, firmware_n=fw)
    return case


def test_score_figures_and_json_shape():
    res = ev.score(make_case())
    e = res["estimators"]
    assert e["lugre-p+loss"]["rope_rms_pct"] == pytest.approx(0.1)
    assert e["raw"]["rope_peak_pct"] == pytest.approx(10.0)
    assert e["raw"]["pithead_total_pct"] == pytest.approx(-20.0)
    assert e["raw"]["pithead_total_basis"] == "arrival"   # no payload given: no empty-cage rest
    assert e["firmware"]["rope_rms_pct"] == pytest.approx(0.11)
    assert e["firmware"]["vs_reference_max_pct"] == pytest.approx(0.01)
    assert e["firmware"]["frames"] == 20
    # raw reads 1000 N low on both ropes, which inflates a deviation. Rope 0 at -8 %
    # (2 ropes of 5000 N): dT = -400 / 0.54 = -740.7 N, estimates 3259.3 and 4000 N,
    # deviation -10.2 %: a false alarm in each of the 18 frames outside the shock
    # (frames 5 and 6 are excluded), for rope 0 and likewise rope 1: 36. At +8 %:
    # dT = 869.6 N, deviation +9.8 %, none. At 12 % the deviation reads 14.6 % or more.
    # Operator alarms (the host's debounce, frames of 0.1 s): frames 0-4 hold the
    # condition 0.4 s, the shock restarts it, frames 7-19 raise at frame 12, on the
    # deviating rope and on the other (two ropes: +10.2 %): 2 false alarms a case, 4.
    assert e["raw"]["alarms"]["8"] == {"frames": 4 * 18, "false": 36, "missed": 0, "detected_frac": 0.5,
                                       "false_alarms": 4, "missed_alarm_frames": 0}
    assert e["raw"]["alarms"]["12"]["missed"] == 0
    assert e["lugre-p+loss"]["alarms"]["8"]["false"] == 0
    doc = json.loads(json.dumps(ev.jsonable({"scenarios": {"hand": res}}), allow_nan=False))
    f = doc["scenarios"]["hand"]["estimators"]["raw"]
    assert {"rope_rms_pct", "rope_peak_pct", "pithead_total_pct"} <= set(f)
    assert f["by_phase"]["acceleration"]["rope_rms_pct"] is None


def test_markdown_marks_targets_and_verdict():
    md = ev.markdown({"scenarios": {"hand": ev.score(make_case()),
                                    "broken": {"error": "simulate: exit 1"}}})
    assert "| lugre-p+loss | 0.10 ok | 0.10 ok | 0.10 | - | 0.20 ok |" in md
    assert "| raw | 10.00 **FAIL** | 10.00 **FAIL** |" in md
    assert "`lugre-p+loss` (0.10 %) beats the best simpler estimator `raw` (10.00 %)" in md
    assert "max 0.0100 % of rated ok" in md
    assert "Not evaluated: simulate: exit 1" in md


def test_plots_are_written(tmp_path):
    case = make_case()
    paths = ev.plot(case, tmp_path)
    paths.append(ev.bar_plot({"scenarios": {"hand": ev.score(case)}}, tmp_path))
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_summary_line_per_scenario():
    md = ev.markdown(ev.jsonable({"scenarios": {"hand": ev.score(make_case()), "broken": {"error": "boom"}}}))
    summary = md.split("## Per scenario")[0]
    assert ("| hand | - | - | - | 0.20 ok | 0.10 ok | 0.10 ok | `raw` 10.00 (full wins) | 0.0100 ok "
            "| 0 / 0 of 72; 0 / 0 |") in summary
    assert "| broken | not evaluated: boom |" in summary


def test_a_failed_commissioning_is_loud():
    res = ev.score(make_case())
    res["commissioning"] = {"ok": False, "problems": ["sigma0 NOT fitted on the test bed (default)"]}
    results = ev.jsonable({"scenarios": {"hand": res, "fine": ev.score(make_case())}})
    assert ev.commissioning_failed(results) == ["hand"]
    md = ev.markdown(results)
    assert md.split("\n")[2].startswith("**COMMISSIONING FAILED for hand**")
    assert "| hand | **FAILED** (see notes) |" in md


def test_a_seal_refusal_fails_only_where_it_is_not_expected():
    """`ropemon config` must refuse the seal of a REFUSAL_EXPECTED scenario (plant-other-friction)
    and no other: either way round the evaluation fails loudly; as expected, it says so."""
    refusal = "friction.standstill_hold_ratio: the seal held 0 % of its sliding force ...; refused"

    def res(refused: bool, expected: bool) -> dict:
        r = ev.score(make_case())
        r["commissioning"] = {"ok": not refused, "problems": [], "seal_refused": refusal if refused else None,
                              "refusal_expected": expected, "sigma0_N_per_m": 1e8}
        return r

    results = ev.jsonable({"scenarios": {"as-expected": res(True, True), "missed": res(False, True),
                                         "false-refusal": res(True, False), "fine": res(False, False)}})
    assert ev.commissioning_failed(results) == ["missed", "false-refusal"]
    md = ev.markdown(results)
    assert "| as-expected | refused by `ropemon config`, as expected (see notes) |" in md
    assert "| missed | **NOT refused** (see notes) |" in md
    assert "| false-refusal | **FAILED** (see notes) |" in md
    assert ev.REFUSAL_EXPECTED == ("plant-other-friction",) and "plant-other-friction" in ev.VARIANTS
