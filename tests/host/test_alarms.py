"""Alarm logic: thresholds, minimum durations, hysteresis, latching, acknowledgement, events;
the sensor_stuck plausibility check."""
from __future__ import annotations

import pytest

from ropemon.station.alarms import AlarmEngine, AlarmSettings
from ropemon.station.alarmstate import Timing
from ropemon.station.decoder import StreamDecoder
from ropemon.station.protocol import L, encode_frame

DT = 0.1  # frame period, s


def frame(tensions, seq=0, node=1, status=0, fault_mask=0, battery_mv=7400, kind=None):
    ropes = [(t, t - 10, t + 10, 5000) if t != L.TENSION_ABSENT else (t, t, t, L.RAW_KPA_ABSENT)
             for t in tensions]
    _, wire = encode_frame(node=node, seq=seq, ropes=ropes, status=status, fault_mask=fault_mask,
                           battery_mv=battery_mv, kind=kind)
    return StreamDecoder().feed(wire)[0]


def run(engine, tension_rows, t0=0.0, **kw):
    """Feed one frame per row at DT spacing; return all events."""
    ev = []
    for i, row in enumerate(tension_rows):
        ev += engine.update(frame(row, seq=i, **kw), t0 + i * DT)
    return ev


def dev_row(frac):
    """Four ropes, rope 3 off the mean by `frac` (of the 4-rope mean)."""
    # ropes 0-2 at b, rope 3 at c; mean m = (3b + c)/4; (c - m)/m = frac -> c = b (1 + frac) * 3 / (3 - frac)
    b = 5000
    c = round(b * 3 * (1 + frac) / (3 - frac))
    return [b, b, b, c]


def ids(events, action=None):
    return [(e.action, e.alarm) for e in events if action is None or e.action == action]


def test_single_noisy_frame_neither_raises_nor_clears():
    eng = AlarmEngine()
    rows = [dev_row(0.0)] * 5 + [dev_row(0.2)] + [dev_row(0.0)] * 5
    assert run(eng, rows) == []
    rows = [dev_row(0.2)] * 10
    ev = run(eng, rows, t0=10)
    assert ids(ev) == [("raise", "deviation:n1:r3")]
    # raised only once the condition held for raise_after_s (0.5 s)
    assert ev[0].time_s == 10 + 0.5
    assert ev[0].value > 0.1 and ev[0].threshold == 0.1 and ev[0].rope == 3
    # operators count ropes from 1: the logged message names the fourth rope "rope 4"
    assert ev[0].message.startswith("rope 4 ")
    one_good = run(eng, [dev_row(0.2)] * 3 + [dev_row(0.0)] + [dev_row(0.2)] * 3, t0=20)
    assert one_good == []


def test_threshold_is_the_configured_fraction():
    assert run(AlarmEngine(), [dev_row(0.095)] * 20) == []
    assert ids(run(AlarmEngine(), [dev_row(0.105)] * 20)) == [("raise", "deviation:n1:r3")]
    assert run(AlarmEngine(AlarmSettings(deviation_frac=0.15)), [dev_row(0.12)] * 20) == []
    # below rope direction too
    assert ids(run(AlarmEngine(), [dev_row(-0.12)] * 20)) == [("raise", "deviation:n1:r3")]


def test_hysteresis_and_clear_duration():
    eng = AlarmEngine()  # 10 % threshold, 2 % hysteresis, clear after 2 s
    run(eng, [dev_row(0.12)] * 10)
    assert run(eng, [dev_row(0.09)] * 50, t0=1) == []        # inside the band: stays raised
    assert [a.present for a in eng.active()] == [True]
    ev = run(eng, [dev_row(0.05)] * 30, t0=6)
    assert ids(ev) == [("clear", "deviation:n1:r3")]
    assert abs(ev[0].time_s - (6 + 2.0)) < 1e-9


def test_latched_until_acknowledged():
    eng = AlarmEngine()
    run(eng, [dev_row(0.2)] * 10)
    run(eng, [dev_row(0.0)] * 30, t0=5)                       # condition gone
    act = eng.active()
    assert [(a.id, a.present, a.latched) for a in act] == [("deviation:n1:r3", False, True)]
    ev = eng.ack("deviation:n1:r3", 9.0)
    assert ids(ev) == [("ack", "deviation:n1:r3")] and ev[0].time_s == 9.0
    assert eng.active() == []
    assert eng.ack("deviation", 9.5) == []                    # nothing left to acknowledge


def test_ack_while_present_keeps_it_visible_and_a_new_raise_latches_again():
    eng = AlarmEngine()
    run(eng, [dev_row(0.2)] * 10)
    eng.ack("*", 1.0)
    assert [(a.present, a.latched) for a in eng.active()] == [(True, False)]
    run(eng, [dev_row(0.0)] * 30, t0=2)
    assert eng.active() == []
    ev = run(eng, [dev_row(0.2)] * 10, t0=10)
    assert ids(ev) == [("raise", "deviation:n1:r3")]
    assert eng.active()[0].latched
    kinds = [e.action for e in eng.events]
    assert kinds == ["raise", "ack", "clear", "raise"]


def test_unloaded_ropes_are_not_judged_for_deviation():
    assert run(AlarmEngine(), [[10, 10, 10, 40]] * 20) == []


def test_overload_and_slack():
    s = AlarmSettings(rated_load_dan=20000, slack_dan=1000)
    eng = AlarmEngine(s)
    assert ids(run(eng, [[5200, 5200, 5200, 5200]] * 10)) == [("raise", "overload:n1")]
    eng2 = AlarmEngine(s)
    assert run(eng2, [[4950, 4950, 4950, 4950]] * 10) == []
    ev = run(eng2, [[5000, 5000, 5000, 800]] * 10, t0=5)
    assert ("raise", "slack:n1:r3") in ids(ev)
    assert ("raise", "deviation:n1:r3") in ids(ev)
    o = [e for e in ev if e.kind == "slack"][0]
    assert o.value == 800 and o.threshold == 1000


def test_fault_bits_config_fault_battery():
    eng = AlarmEngine(AlarmSettings(battery_low_mv=6800))
    ev = run(eng, [[5000] * 4] * 3, status=L.ST_PRESSURE_FAULT, fault_mask=0b0100)
    assert ids(ev) == [("raise", "sensor_fault:n1")]
    assert ev[0].value == 4 and "pressure_fault" in ev[0].message
    cfg = [eng.update(frame([], seq=i, status=L.ST_CONFIG_FAULT), 5 + i * DT) for i in range(3)]
    assert ("raise", "config_fault:n1") in ids(sum(cfg, []))
    ev = run(eng, [[5000] * 4] * 10, t0=10, battery_mv=6500)
    assert ("raise", "battery_low:n1") in ids(ev)
    eng2 = AlarmEngine()
    assert ids(run(eng2, [[5000] * 4] * 10, status=L.ST_BATTERY_LOW)) == [("raise", "battery_low:n1")]


def test_the_nodes_noise_changed_bit_raises_pressure_noise_and_clears():
    eng = AlarmEngine()
    assert ids(run(eng, [[5000] * 4])) == []  # one frame is not an alarm
    ev = run(eng, [[5000] * 4] * 3, t0=1, status=L.ST_NOISE_CHANGED)
    assert ids(ev) == [("raise", "pressure_noise:n1")]
    assert "more than 25 % off the commissioned" in ev[0].message and "fit-compliance --check" in ev[0].message
    ev = run(eng, [[5000] * 4] * 30, t0=2)  # 2 s without the bit
    assert ("clear", "pressure_noise:n1") in ids(ev)


def test_node_silent_raises_on_tick_and_clears_when_frames_return():
    eng = AlarmEngine(AlarmSettings(silent_s=5.0))
    run(eng, [[5000] * 4] * 3)
    assert eng.tick(4.0) == []
    ev = eng.tick(5.3)
    assert ids(ev) == [("raise", "silent:n1")] and ev[0].value > 5.0
    ev = run(eng, [[5000] * 4] * 15, t0=6)
    assert ids(ev) == [("clear", "silent:n1")]
    assert eng.active()[0].latched and not eng.active()[0].present


def test_link_integrity_from_decoder_counts():
    eng = AlarmEngine(AlarmSettings(link_timing=Timing(raise_after_s=0, clear_after_s=10, min_frames=1)))
    assert eng.update_link("pithead", 0, 0, 1.0) == []
    ev = eng.update_link("pithead", 1, 0, 2.0)
    assert ids(ev) == [("raise", "link_integrity:pithead")]
    assert eng.update_link("pithead", 1, 0, 5.0) == []         # no new failures, not yet 10 s
    assert eng.update_link("pithead", 1, 2, 6.0) == []         # new replays restart the clear timer
    assert eng.update_link("pithead", 1, 2, 7.0) == []
    assert ids(eng.update_link("pithead", 1, 2, 17.0)) == [("clear", "link_integrity:pithead")]


def test_settings_from_loads():
    s = AlarmSettings.from_loads(rated_load_dan=30000, empty_load_dan=18540, n_ropes=4)
    assert s.slack_dan == round(0.6 * 18540 / 4) and s.rated_load_dan == 30000
    eng = AlarmEngine(s)
    ev = run(eng, [[4600, 4600, 4600, 2700]] * 10)
    assert ("raise", "slack:n1:r3") in ids(ev)
    assert "slack" not in {e.kind for e in run(AlarmEngine(s), [[4600, 4600, 4600, 2900]] * 10)}


def test_one_frame_with_a_fault_bit_is_not_an_alarm():
    eng = AlarmEngine()
    ev = eng.update(frame([5000] * 4, seq=0, status=L.ST_DISPLACEMENT_FAULT, fault_mask=0x10), 0.0)
    ev += run(eng, [[5000] * 4] * 5, t0=0.1)
    assert ev == [] and eng.active() == []


def test_absent_rope_is_not_judged_and_not_averaged():
    A = L.TENSION_ABSENT
    s = AlarmSettings(rated_load_dan=20000, slack_dan=1000)
    eng = AlarmEngine(s)
    ev = run(eng, [[5000, 5000, A, 5000]] * 20, status=L.ST_PRESSURE_FAULT, fault_mask=0b0100)
    assert ids(ev) == [("raise", "sensor_fault:n1")]
    # The total is estimated at the mean of the present ropes: 4 x 5300 > 20000.
    ev = run(eng, [[5300, 5300, A, 5300]] * 20, t0=5, status=L.ST_PRESSURE_FAULT, fault_mask=0b0100)
    assert ids(ev) == [("raise", "overload:n1")] and "estimated" in ev[0].message
    f = frame([5000, A, 5000, 5000])
    assert f.ropes[1].absent and f.tensions_n == [50000, None, 50000, 50000] and f.total_dan is None


# -- sensor_stuck: a transmitter frozen at a plausible value inside 4-20 mA ----------------------

def raw_frame(raw_kpas, seq=0, node=1):
    """Ropes given by raw_kpa (tension taken equal to it, in daN); None = absent rope."""
    ropes = [(k, k - 10, k + 10, k) if k is not None
             else (L.TENSION_ABSENT, L.TENSION_ABSENT, L.TENSION_ABSENT, L.RAW_KPA_ABSENT) for k in raw_kpas]
    _, wire = encode_frame(node=node, seq=seq, ropes=ropes)
    return StreamDecoder().feed(wire)[0]


def run_raw(engine, rows, t0=0.0, kind="sensor_stuck"):
    """Feed one frame per row of raw_kpa at DT spacing; return the events of `kind`."""
    ev = []
    for i, row in enumerate(rows):
        ev += engine.update(raw_frame(row, seq=i), t0 + i * DT)
    return [e for e in ev if e.kind == kind]


def jitter(i, amp=1):
    """Deterministic +-amp kPa wobble, like a window mean's last digit."""
    return (0, amp, -amp, amp, 0, -amp, 0)[i % 7]


def ramp_rows(n, frozen=(1,), start=5000, kpa_per_s=40.0, noise=3, frozen_kpa=5000, i0=0, adc=1):
    """Four ropes: the live ones ramp with noise, the `frozen` ones hold frozen_kpa +- adc kPa."""
    rows = []
    for k in range(i0, i0 + n):
        live = start + round(kpa_per_s * k * DT)
        rows.append([frozen_kpa + jitter(k, adc) if r in frozen else live + jitter(k + 2 * r, noise)
                     for r in range(4)])
    return rows


def test_stuck_rope_raises_while_the_others_ramp():
    eng = AlarmEngine()
    ev = run_raw(eng, ramp_rows(100))
    assert ids(ev) == [("raise", "sensor_stuck:n1:r1")]
    e = ev[0]
    # still for stuck_s (5 s) with the others 200 kPa away, then the usual raise_after_s (0.5 s)
    assert abs(e.time_s - 5.5) < 1e-9
    assert e.rope == 1 and e.node == 1 and e.threshold == 5.0 and e.value >= 5.0
    assert e.message.startswith("rope 2 pressure 500") and "transmitter stuck" in e.message
    assert [(a.id, a.present, a.latched) for a in eng.active() if a.kind == "sensor_stuck"] == \
        [("sensor_stuck:n1:r1", True, True)]
    assert e in eng.events
    # ADC noise behind the frozen loop current (+-3 kPa in the window mean) does not hide it
    assert ids(run_raw(AlarmEngine(), ramp_rows(100, adc=3))) == [("raise", "sensor_stuck:n1:r1")]
    # a wider wobble is movement (a live transmitter's noise): not called stuck
    assert run_raw(AlarmEngine(), ramp_rows(100, adc=6)) == []


def test_stuck_needs_stuck_s_of_stillness_and_the_others_beyond_the_threshold():
    # frozen only 4 s before the others' ramp stops being informative: no alarm yet
    assert run_raw(AlarmEngine(), ramp_rows(45)) == []
    # the others move 40 kPa in all (below 50): not evidence, however long
    slow = ramp_rows(200, kpa_per_s=2.0, noise=0)
    assert run_raw(AlarmEngine(), slow) == []
    assert ids(run_raw(AlarmEngine(AlarmSettings(stuck_others_kpa=30)), slow)) == \
        [("raise", "sensor_stuck:n1:r1")]
    # a longer stuck_s waits longer
    ev = run_raw(AlarmEngine(AlarmSettings(stuck_s=8.0)), ramp_rows(120))
    assert [round(e.time_s, 6) for e in ev] == [8.5]
    assert run_raw(AlarmEngine(AlarmSettings(stuck_s=None)), ramp_rows(200)) == []


def test_stuck_not_raised_at_rest():
    # every rope still (a quiet transmitter's window mean barely moves): nobody moved, no evidence
    rows = [[5000 + jitter(k + r) for r in range(4)] for k in range(600)]
    assert run_raw(AlarmEngine(), rows) == []
    # ropes at rest with a typical transmitter noise: nothing either
    rows = [[5000 + jitter(k + r, 4) for r in range(4)] for k in range(600)]
    assert run_raw(AlarmEngine(), rows) == []


def test_live_ropes_not_raised_while_winding():
    # every rope moves with the load, with noise: none is stuck
    assert run_raw(AlarmEngine(), ramp_rows(300, frozen=())) == []
    # up and down (acceleration, deceleration), still between: all ropes follow
    rows = []
    for k in range(400):
        phase = (k // 50) % 4
        base = 5000 + (0, 300, 300, 0)[phase] + ((k % 50) * 6 if phase == 0 else
                                                   -(k % 50) * 6 if phase == 2 else 0)
        rows.append([base + jitter(k + r) for r in range(4)])
    assert run_raw(AlarmEngine(), rows) == []


def test_a_quiet_rope_at_rest_that_moves_with_the_others_is_not_stuck():
    # 20 s at rest (rope 2 perfectly still), then all ropes ramp: rope 2 follows them
    rest = [[5000 + jitter(k, 3), 5000, 5000 + jitter(k + 3, 3), 5000 + jitter(k + 5, 3)] for k in range(200)]
    ramp = ramp_rows(100, frozen=(), i0=0)
    assert run_raw(AlarmEngine(), rest + ramp) == []


def test_stuck_clears_with_hysteresis_latches_and_acks():
    eng = AlarmEngine()
    run_raw(eng, ramp_rows(100))
    # one jump of the stuck rope is not recovery: the rope must keep moving for clear_after_s
    blip = ramp_rows(40, i0=100)
    blip[0][1] += 20
    assert run_raw(eng, blip, t0=10.0) == []
    assert [a.present for a in eng.active() if a.kind == "sensor_stuck"] == [True]
    # the rope moves with the others again: clears after clear_after_s (2 s), stays latched
    ev = run_raw(eng, ramp_rows(40, frozen=(), i0=140), t0=14.0)
    assert ids(ev) == [("clear", "sensor_stuck:n1:r1")]
    assert abs(ev[0].time_s - 16.0) < 1e-9 and ev[0].message.startswith("cleared: rope 2 ")
    act = [a for a in eng.active() if a.kind == "sensor_stuck"]
    assert [(a.present, a.latched) for a in act] == [(False, True)]
    ack = eng.ack("sensor_stuck", 20.0)
    assert ids(ack) == [("ack", "sensor_stuck:n1:r1")]
    assert [a for a in eng.active() if a.kind == "sensor_stuck"] == []
    assert [e.action for e in eng.events if e.kind == "sensor_stuck"] == ["raise", "clear", "ack"]


def test_absent_rope_is_not_judged_stuck_and_the_others_still_are():
    # rope 2 absent (open loop) while the others ramp: no stuck alarm for it
    rows = [[r if j != 1 else None for j, r in enumerate(row)] for row in ramp_rows(200, frozen=())]
    assert run_raw(AlarmEngine(), rows) == []
    # rope 4 frozen while ropes 1 and 3 ramp and rope 2 is absent: rope 4 is stuck
    rows = [[r if j != 1 else None for j, r in enumerate(row)] for row in ramp_rows(100, frozen=(3,))]
    assert ids(run_raw(AlarmEngine(), rows)) == [("raise", "sensor_stuck:n1:r3")]
    # a rope dropping out and back changes the others' mean: no false alarm, anchors restart
    rows = ramp_rows(300, frozen=())
    for k in range(100, 110):
        rows[k][2] = None
    assert run_raw(AlarmEngine(), rows) == []
    # a rope frozen for 3 s that then goes absent while the others ramp: held, not judged absent
    rows = ramp_rows(130)
    for k in range(30, 130):
        rows[k][1] = None
    assert run_raw(AlarmEngine(), rows) == []
    # at rest with unequal ropes, rope 3 dropping out shifts the others' mean by 100 kPa: that is
    # not the others moving, so the still ropes are not called stuck
    rest = [[5000 + jitter(k), 5000 + jitter(k + 1), 5300 + jitter(k + 2), 4700 + jitter(k + 3)]
            for k in range(200)]
    for k in range(50, 70):
        rest[k][2] = None
    assert run_raw(AlarmEngine(), rest) == []
    # only one rope left: nothing to compare it with
    assert run_raw(AlarmEngine(), [[5000, None, None, None]] * 100 + [[5000, None, None, None]]) == []


def test_stuck_is_per_node():
    eng = AlarmEngine()
    ev = []
    stuck, live = ramp_rows(100), ramp_rows(100, frozen=())
    for i in range(100):
        ev += eng.update(raw_frame(stuck[i], seq=i, node=1), i * DT)
        ev += eng.update(raw_frame(live[i], seq=i, node=2), i * DT + 0.01)
    assert ids([e for e in ev if e.kind == "sensor_stuck"]) == [("raise", "sensor_stuck:n1:r1")]


@pytest.mark.parametrize("scenario, expected", [
    ("stuck-sensor", [("raise", "sensor_stuck:n1:r1")]),   # rope 2 frozen from 30 s on
    ("paper-field-trip", []),                                # the same wind, every transmitter live
])
def test_stuck_on_the_evaluation_streams_through_the_firmware(tmp_path, capsys, scenario, expected):
    """The accuracy evaluation's wind (128 s), simulated, run through the firmware in micropython."""
    import json

    from ropemon.cli import main
    from ropemon.lab.demo import read_frames_bin
    from ropemon.lab.evaluate import simulate

    simulate(scenario, tmp_path, seed=1)
    out = tmp_path / "frames.bin"
    assert main(["replay", str(tmp_path / "sensors.rsens"), "--out", str(out),
                 "--config", str(tmp_path / "node.json")]) == 0
    nd = json.loads((tmp_path / "node.json").read_text())["node"]  # the node's id and key: its section
    frames = read_frames_bin(out, {nd["node_id"]: bytes(nd["key"])}).frames
    assert len(frames) > 1000 and all(len(f.ropes) == 4 for f in frames)
    eng = AlarmEngine()
    ev = [e for f in frames for e in eng.update(f, f.time_ms / 1000) if e.kind == "sensor_stuck"]
    assert ids(ev) == expected
    if expected:
        assert 35.0 <= ev[0].time_s <= 37.0 and ev[0].message.startswith("rope 2 ")


def test_debounced_series_is_the_engines_debounce():
    """`debounced` (what the evaluation counts) jumps over idle stretches; it must give the
    same raises and the same debounced condition as stepping `Debounce` frame by frame, as
    the engine does, skipped frames included."""
    import numpy as np

    from ropemon.station.alarmstate import Debounce
    from ropemon.lab.metrics import debounced

    rng = np.random.default_rng(7)
    timing = AlarmSettings().timing
    for trial in range(40):
        n = 400
        dev = np.cumsum(rng.normal(0, 0.01, n)) + rng.normal(0, 0.01, n) + 0.09
        times = np.arange(n) * DT
        skip = rng.random(n) < (0.05 if trial % 2 else 0.0)
        rc, cc = dev > 0.10, dev < 0.08
        present, raises = debounced(times, rc, cc, timing, skip)
        d, want_present, want_raises = Debounce(timing), [], []
        for i in range(n):
            if skip[i]:
                d.since_s, d.since_n = None, 0
            elif d.step(times[i], rc[i], cc[i]) == "raise":
                want_raises.append(i)
            want_present.append(d.present)
        assert raises == want_raises
        assert present.tolist() == want_present


def test_debounced_raises_after_the_engines_hold():
    import numpy as np

    from ropemon.lab.metrics import debounced

    times = np.arange(10) * DT
    cond = np.array([False, True, True, True, True, True, True, False, False, False])
    present, raises = debounced(times, cond, ~cond, AlarmSettings().timing)
    assert raises == [6]  # 0.5 s after frame 1, as the engine (test_single_noisy_frame_...)
    assert present.tolist() == [False] * 6 + [True] * 4  # clearing takes 2 s below
    short = cond & (np.arange(10) < 5)  # 0.3 s of condition: no alarm
    assert debounced(times, short, ~short, AlarmSettings().timing)[1] == []


def test_a_hold_of_whole_frame_periods_does_not_depend_on_float_rounding():
    import numpy as np

    from ropemon.lab.metrics import debounced

    times = np.arange(100) * DT  # 43 * 0.1 - 38 * 0.1 < 0.5 in floats
    assert times[43] - times[38] < 0.5
    for start in (0, 38):
        cond = np.zeros(100, bool)
        cond[start:start + 6] = True  # six frames: held 0.5 s at the sixth
        assert debounced(times, cond, ~cond, AlarmSettings().timing)[1] == [start + 5]
        eng = AlarmEngine()
        rows = [dev_row(0.0)] * start + [dev_row(0.2)] * 6 + [dev_row(0.0)] * 4
        ev = [e for i, row in enumerate(rows) for e in eng.update(frame(row, seq=i), times[i])]
        assert ids(ev) == [("raise", "deviation:n1:r3")], start


# ---------------------------------------------------------------- deviation_possible: the band
# DEVIATION POSSIBLE is the station before it watched the equalizer (the evaluation's baseline):
# `legacy_deviation_possible=True, equalizer=None`. The station as it is raises none (below).

LEGACY = {"legacy_deviation_possible": True, "equalizer": None}

BAND_PHYS = {"ropes": 4, "cylinder_area_m2": [0.01] * 4,   # 1 kPa -> 10 N
             "friction": {"Fs": {"intercept": 0.0, "slope": 600.0}, "Fc": {"intercept": 0.0, "slope": 400.0},
                          "residual": 50.0},
             "band_anchor": True, "band_margin": 0.10}   # the anchor's path (opt-in)


def test_legacy_seals_that_can_hold_the_limit_keep_deviation_possible_standing():
    """The legacy station, anchoring off (the default): the band is the seals' physical range.
    Seals whose static friction can hold more than 10 % of the mean keep DEVIATION POSSIBLE
    standing on every rope at 0 % shown; seals that cannot (a light seal) raise nothing."""
    from ropemon.station.uncertainty import BandParams

    def run(slope):
        phys = {**BAND_PHYS, "friction": {"Fs": {"intercept": 0.0, "slope": slope},
                                          "Fc": {"intercept": 0.0, "slope": 0.6 * slope}, "residual": 10.0}}
        del phys["band_anchor"], phys["band_margin"]
        eng = AlarmEngine(AlarmSettings(band=BandParams.from_physical(phys), **LEGACY))
        for k in range(30):
            eng.update(band_frame([(5200, 0.0)] * 4, k), k * DT)
        return sorted(a.rope for a in eng.active() if a.kind == "deviation_possible")

    # p = 5.2 MPa: Fs = 3.1 kN of 52 kN (6 %, x1.25 = 7.5 %: with the others' band it reaches 10 %)
    assert run(600.0) == [0, 1, 2, 3]
    assert run(100.0) == []     # 0.5 kN: no seal can hold 10 %


def test_deviation_possible_clears_when_the_ropes_are_unloaded():
    """Below the deviation check's minimum mean (unloaded ropes) neither alarm is judged: the
    warning clears as the certain alarm does, it does not stand for ever."""
    from ropemon.station.uncertainty import BandParams

    phys = {k: v for k, v in BAND_PHYS.items() if k not in ("band_anchor", "band_margin")}
    eng = AlarmEngine(AlarmSettings(band=BandParams.from_physical(phys), **LEGACY))
    k = 0
    for k in range(30):
        eng.update(band_frame([(5200, 0.0)] * 4, k), k * DT)
    assert {a.kind for a in eng.active() if a.present} == {"deviation_possible"}
    for k in range(30, 70):
        eng.update(band_frame([(50, 0.0)] * 4, k), k * DT)
    assert not [a for a in eng.active() if a.present and a.kind == "deviation_possible"]


def band_engine(**kw):
    from ropemon.station.uncertainty import BandParams
    return AlarmEngine(AlarmSettings(band=BandParams.from_physical(BAND_PHYS), **{**LEGACY, **kw}))


def band_frame(ropes, seq, fault_mask=0):
    """ropes: per rope (tension daN, friction estimate N): its raw pressure is (T - F) / A."""
    from ropemon.station.protocol import Frame, Rope
    recs = tuple(Rope(t, t, t, round((t * 10 - f) / 10)) for t, f in ropes)
    return Frame(1, 0, 1, fault_mask, seq, seq * 100, 0, recs, 0, 0, 7400, L.OIL_TEMP_ABSENT)


class BandRun:
    """Frames at DT; first every rope's estimate driven to +2 kN (Fc) by a pressure rise of 10 kN of
    p A, beyond S: every rope anchored, the band at its floor (100 N)."""

    def __init__(self, **kw):
        self.eng, self.seq, self.events = band_engine(**kw), 0, []
        for k in range(11):
            self.feed([(4200 + 100 * k, 2000.0)] * 4)

    def feed(self, ropes, n=1, **kw):
        for _ in range(n):
            self.events += self.eng.update(band_frame(ropes, self.seq, **kw), self.seq * DT)
            self.seq += 1
        return self

    def kinds(self):
        return {a.kind for a in self.eng.active()}


def off_by(frac, f3=2000.0):
    """Ropes 1-3 at 5200 daN (estimate +2 kN), rope 4 `frac` off their mean, with estimate f3."""
    c = round(5200 * 3 * (1 + frac) / (3 - frac))
    return [(5200, 2000.0)] * 3 + [(c, f3)]


def test_six_percent_with_a_small_band_raises_nothing():
    r = BandRun().feed(off_by(0.06), n=30)
    b = r.eng.deviation_bands(1)[3]
    assert b.dev == pytest.approx(0.06, abs=1e-3) and b.band < 0.01
    assert r.events == []


def test_six_percent_whose_band_reaches_ten_raises_deviation_possible_only():
    """Rope 4's estimate flipped to -2 kN with its pressure barely moved: the seal may still hold +2 kN."""
    r = BandRun().feed(off_by(0.06, f3=-2000.0), n=30)
    b = r.eng.deviation_bands(1)[3]
    assert b.dev == pytest.approx(0.06, abs=1e-3) and abs(b.dev) + b.band >= 0.10
    assert ids(r.events) == [("raise", "deviation_possible:n1:r3")]
    ev = r.events[0]
    assert ev.time_s - (11 * DT) == pytest.approx(0.5)          # the deviation alarm's debounce
    assert ev.kind == "deviation_possible" and ev.rope == 3 and ev.value == pytest.approx(0.06, abs=1e-3)
    assert ev.message.startswith("rope 4 +6.0% +-") and "(limit 10%)" in ev.message and "next landing" in ev.message
    (a,) = r.eng.active()
    assert a.warning and a.band == pytest.approx(b.band, abs=1e-4)


def test_twelve_percent_raises_deviation_and_the_warning_yields_to_it():
    r = BandRun().feed(off_by(0.12), n=30)
    assert ids(r.events) == [("raise", "deviation:n1:r3")]
    r = BandRun().feed(off_by(0.06, f3=-2000.0), n=10)
    assert r.kinds() == {"deviation_possible"}
    r.feed(off_by(0.12, f3=-2000.0), n=40)
    assert ("raise", "deviation:n1:r3") in ids(r.events)
    assert ("clear", "deviation_possible:n1:r3") in ids(r.events)
    assert [a.kind for a in r.eng.active() if a.present] == ["deviation"]


def test_deviation_possible_clears_with_hysteresis():
    r = BandRun().feed(off_by(0.06, f3=-2000.0), n=10)
    r.eng.ack("*", r.seq * DT)
    r.feed(off_by(0.0), n=5)                               # anchor not yet confirmed: the band is still wide
    # back to the anchor's side, driven again: the band shrinks to the floor and the warning clears
    for k in range(11):
        r.feed([(5200 + 100 * k, 2000.0)] * 4)
    r.feed([(6200, 2000.0)] * 4, n=25)
    assert ("clear", "deviation_possible:n1:r3") in ids(r.events)
    assert r.eng.active() == []


def test_the_warning_raises_while_frames_stop_before_node_silent():
    """Not green while blind: without frames the band widens to the physical range over 2 s."""
    r = BandRun().feed(off_by(0.06), n=10)
    assert r.events == []
    t0 = (r.seq - 1) * DT
    ev = []
    for k in range(1, 16):
        ev += r.eng.tick(t0 + 0.25 * k)                     # up to 3.75 s: node silent only after 5 s
    assert ("raise", "deviation_possible:n1:r3") in ids(ev)
    assert "silent" not in {e.kind for e in ev}
    assert "no frame for" in next(e.message for e in ev if e.kind == "deviation_possible")


def test_a_rope_without_tension_raises_sensor_fault_and_is_not_judged_possible():
    r = BandRun()
    absent = band_frame([(5200, 2000.0)] * 4, 0)
    ropes = list(absent.ropes)
    ropes[1] = ropes[1]._replace(mean_dan=L.TENSION_ABSENT, min_dan=L.TENSION_ABSENT, max_dan=L.TENSION_ABSENT,
                                 raw_kpa=L.RAW_KPA_ABSENT)
    for _ in range(10):
        f = band_frame([(5200, 2000.0)] * 4, r.seq, fault_mask=0x02)
        f.ropes = tuple(ropes)
        r.events += r.eng.update(f, r.seq * DT)
        r.seq += 1
    kinds = r.kinds()
    assert "sensor_fault" in kinds
    assert not any(a.kind == "deviation_possible" and a.rope == 1 for a in r.eng.active())
    assert r.eng.deviation_bands(1)[1] is None


def test_the_station_raises_no_standing_warning_and_states_the_hidden_imbalance():
    """Where the legacy station keeps DEVIATION POSSIBLE standing on every rope (seals that can
    hold the limit), the station raises nothing: the imbalance the seals can hide is the hoist's
    standing status, at the current mean rope tension, with the band beside each deviation."""
    from ropemon.station.uncertainty import BandParams, hidden_reach

    phys = {**BAND_PHYS, "friction": {"Fs": {"intercept": 0.0, "slope": 600.0},
                                      "Fc": {"intercept": 0.0, "slope": 360.0}, "residual": 10.0}}
    del phys["band_anchor"], phys["band_margin"]
    band = BandParams.from_physical(phys)
    for legacy, expect in ((True, [0, 1, 2, 3]), (False, [])):
        eng = AlarmEngine(AlarmSettings(band=band, legacy_deviation_possible=legacy))
        ev = []
        for k in range(600):                                # a minute at rest
            ev += eng.update(band_frame([(5200, 0.0)] * 4, k), k * DT)
        assert sorted(a.rope for a in eng.active() if a.kind == "deviation_possible") == expect
        if not legacy:
            assert ev == [] and eng.active() == []
            st = eng.hoist_status(1)
            assert st.hidden_frac == pytest.approx(hidden_reach(band, 52000.0)) and st.hidden_frac > 0.10
            assert st.rope_n == pytest.approx(52000.0) and st.limit == 0.10
            assert "can hide an imbalance up to" in st.text and "52.0 kN per rope (limit 10%)" in st.text
            assert [b is not None and b.reach > 0.10 for b in eng.deviation_bands(1)] == [True] * 4
            assert eng.hoist_status(2) is None              # never heard


def test_hoist_status_without_a_band_is_none_and_names_a_version_2_node():
    eng = AlarmEngine()
    run(eng, [dev_row(0.0)] * 3)
    assert eng.hoist_status(1) is None
    from ropemon.station.protocol import Frame, Rope
    f = Frame(2, 0, 1, 0, 9, 900, 0, (Rope(5000, 5000, 5000, 5000),) * 4, 0, 0, 7400, L.OIL_TEMP_ABSENT)
    eng.update(f, 10.0)
    st = eng.hoist_status(1)
    assert st.hidden_frac is None and st.positions is False
    assert "node 1 sends no piston positions (layout version 2)" in st.text


def test_without_friction_lines_there_is_no_band():
    eng = AlarmEngine()
    assert run(eng, [dev_row(0.06)] * 20) == [] and eng.deviation_bands(1) == []
