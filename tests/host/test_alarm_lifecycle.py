"""The alarm lifecycle (ISA-18.2 states, worst value, who acknowledged, shelving, out of service,
suppression by design, flood) and the deviation threshold exactly at its edge."""
from __future__ import annotations

import pytest

from ropemon.station.alarms import AlarmEngine, AlarmSettings, FLOOD_RAISES
from ropemon.station.protocol import L
from test_alarms import DT, dev_row, frame, run


def state(eng: AlarmEngine, aid: str) -> str:
    for a in eng.active() + eng.hidden():
        if a.id == aid:
            return a.state
    return "normal"


@pytest.mark.parametrize("frac, raised", [(0.0999, False), (0.1001, True)])
def test_the_deviation_limit_is_ten_percent_to_the_hundredth(frac, raised):
    eng = AlarmEngine(AlarmSettings(deviation_frac=0.10))
    b = 25_000                                   # large tensions: the daN rounding stays below 0.002 %
    c = round(b * 3 * (1 + frac) / (3 - frac))
    ev = run(eng, [[b, b, b, c]] * 10)
    assert [e.alarm for e in ev if e.action == "raise"] == (["deviation:n1:r3"] if raised else [])


def test_states_worst_value_and_who_acknowledged():
    eng = AlarmEngine()
    aid = "deviation:n1:r3"
    run(eng, [dev_row(0.12)] * 6 + [dev_row(0.158)] * 3 + [dev_row(0.13)] * 3)
    assert state(eng, aid) == "unacknowledged"
    a = eng.active()[0]
    assert a.worst == pytest.approx(0.158, abs=1e-3) and a.value == pytest.approx(0.13, abs=1e-3)
    run(eng, [[5000] * 4] * 30, t0=2.0)          # back to normal before anyone acknowledged
    assert state(eng, aid) == "rtn_unacknowledged"
    a = eng.active()[0]
    assert not a.present and a.worst == pytest.approx(0.158, abs=1e-3) and a.cleared_s is not None
    ev = eng.ack("*", 6.0, "alice (terminal)")
    assert ev[0].operator == "alice (terminal)" and ev[0].worst == pytest.approx(0.158, abs=1e-3)
    assert eng.active() == []                    # acknowledged and cleared: gone


def test_shelved_alarm_is_not_annunciated_until_it_expires_and_needs_a_reason():
    eng = AlarmEngine()
    aid = "deviation:n1:r3"
    run(eng, [dev_row(0.2)] * 10)
    with pytest.raises(ValueError):
        eng.shelve(aid, 1.0, 600.0, " ", "bob")
    with pytest.raises(KeyError):
        eng.shelve("deviation:n9:r0", 1.0, 600.0, "no such", "bob")
    ev = eng.shelve(aid, 1.0, 601.0, "rope change on the bench", "bob (web)")
    assert ev[0].action == "shelve" and ev[0].operator == "bob (web)"
    assert eng.active() == [] and state(eng, aid) == "shelved"
    run(eng, [dev_row(0.2)] * 10, t0=2.0)        # still evaluated, not annunciated
    assert eng.active() == []
    ev = eng.tick(601.5)                          # expired: back, present, to be acknowledged
    assert [e.action for e in ev if e.alarm == aid] == ["unshelve"]
    assert state(eng, aid) == "unacknowledged"


def test_out_of_service_and_back():
    eng = AlarmEngine()
    aid = "battery_low:n1"
    run(eng, [[5000] * 4] * 10, status=L.ST_BATTERY_LOW)
    eng.remove_from_service(aid, 2.0, "battery swap", "carol (terminal)")
    assert state(eng, aid) == "out_of_service" and not [a for a in eng.active() if a.id == aid]
    eng.return_to_service(aid, 3.0, "carol (terminal)")
    assert state(eng, aid) == "unacknowledged"


def test_a_faulted_ropes_deviation_is_suppressed_by_design():
    eng = AlarmEngine()
    run(eng, [dev_row(0.2)] * 10)
    faulted = [5000, 5000, 5000, L.TENSION_ABSENT]
    run(eng, [faulted] * 5, t0=1.0, status=L.ST_PRESSURE_FAULT, fault_mask=0x08)
    assert state(eng, "deviation:n1:r3") == "suppressed"
    fault = [a for a in eng.active() if a.kind == "sensor_fault"][0]
    assert "pressure loop of rope 4" in fault.message


def test_more_than_ten_raises_in_ten_minutes_is_an_alarm_flood():
    eng = AlarmEngine(AlarmSettings(stuck_s=None))
    t = 0.0
    for k in range(FLOOD_RAISES + 1):             # one rope after another, a minute apart
        node = k + 1
        for i in range(10):
            eng.update(frame(dev_row(0.2), seq=i, node=node), t + i * DT)
        t += 30.0
        eng.tick(t)
    assert "alarm_flood" in [a.kind for a in eng.active()]


def test_an_equalizer_alarm_goes_through_the_lifecycle():
    """STROKE LIMIT (ropemon.station.equalizer): raised, returned to normal unacknowledged with its
    worst position, acknowledged by whom; taken out of service it is still evaluated and logged,
    not annunciated, and counts for no flood."""
    from ropemon.station.equalizer import EqualizerSettings
    from ropemon.station.protocol import Frame, Rope

    def pframe(x2_m, seq):
        recs = tuple(Rope(5000, 5000, 5000, 6000, round(x * 1e4)) for x in (0.0, x2_m, 0.0, 0.0))
        return Frame(3, 0, 1, 0, seq, seq * 100, 0, recs, 0, 0, 7400, L.OIL_TEMP_ABSENT, stroke_mask=0)

    eq = EqualizerSettings(stroke_m=(0.2,) * 4, margin_m=0.01)
    eng = AlarmEngine(AlarmSettings(equalizer=eq, stuck_s=None))
    aid = "stroke_limit:n1:r1"
    seq = 0
    for x in (0.091, 0.094, 0.092) + (0.080,) * 25:
        eng.update(pframe(x, seq), seq * DT)
        seq += 1
    assert state(eng, aid) == "rtn_unacknowledged"
    (a,) = eng.active()
    assert a.worst == 94.0 and a.priority == 1 and not a.warning
    eng.ack(aid, seq * DT, "carol")
    assert state(eng, aid) == "normal"
    eng.remove_from_service(aid, seq * DT, "cylinder refilled, transmitter re-zeroed", "dave")
    ev = []
    for x in (0.095,) * 3:
        ev += eng.update(pframe(x, seq), seq * DT)
        seq += 1
    assert [(e.action, e.annunciated) for e in ev] == [("raise", False)]
    assert eng.active() == [] and state(eng, aid) == "out_of_service"
    assert list(eng._raises) == [0.0]           # the flood count: the annunciated raise only
    eng.return_to_service(aid, seq * DT, "dave")
    assert state(eng, aid) == "unacknowledged"
