"""Alarm logic: thresholds, minimum durations, hysteresis, latching, acknowledgement, events."""
from __future__ import annotations

from ropemon.alarms import AlarmEngine, AlarmSettings, Timing
from ropemon.decoder import StreamDecoder
from ropemon.protocol import L, encode_frame

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
