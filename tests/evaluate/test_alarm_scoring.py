"""The Targets' scoring of the station's alarm events (ropemon.lab.metrics), on hand-made event
lists: a healthy wind's standing, raised and chattering alarms and what does not count; a fault
alarmed in time, late, on the wrong rope, not at all; the ropes left silent, split by the
imbalance the seals can hide."""
from __future__ import annotations

import numpy as np
import pytest

from ropemon.lab import metrics as M
from ropemon.station.alarms import AlarmEvent


def ev(t, action, kind, rope=None, node=1, annunciated=True):
    aid = f"{kind}:n{node}" + (f":r{rope}" if rope is not None else "")
    return AlarmEvent(time_s=t, action=action, alarm=aid, kind=kind, node=node, rope=rope, value=None,
                      threshold=None, message="", annunciated=annunciated)


def test_spans_pair_raises_with_clears_and_keep_the_unclear_open():
    events = [ev(1.0, "raise", "deviation", 0), ev(2.0, "ack", "deviation", 0), ev(5.0, "clear", "deviation", 0),
              ev(7.0, "raise", "deviation", 0), ev(3.0, "raise", "oil_loss"),
              ev(4.0, "clear", "stroke_limit", 2),                        # a clear without a raise: ignored
              ev(6.0, "raise", "slack", 1, annunciated=False)]           # suppressed: no span
    spans = M.alarm_spans(events)
    assert [(s.alarm, s.t_raise, s.t_clear) for s in spans] == [
        ("deviation:n1:r0", 1.0, 5.0), ("oil_loss:n1", 3.0, None), ("deviation:n1:r0", 7.0, None)]
    # dicts (AlarmEvent.to_dict, the log's rows) score the same
    assert M.alarm_spans([e.to_dict() for e in events]) == spans


def test_a_healthy_wind_standing_raised_chattering_and_what_does_not_count():
    times = np.arange(1, 1301) * 0.1                   # a 130 s wind, frames at 10 Hz
    beyond = np.zeros((len(times), 4), bool)
    beyond[(times >= 50) & (times <= 60), 2] = True    # rope 3 truly beyond the limit 50-60 s
    events = [
        ev(0.6, "raise", "deviation_possible", 0),     # stands: 0.6 s to the end, over all the wind 13-110 s
        ev(20.0, "raise", "not_equalizing", 1), ev(21.0, "clear", "not_equalizing", 1),  # raised 3x in 40 s:
        ev(30.0, "raise", "not_equalizing", 1), ev(31.0, "clear", "not_equalizing", 1),  # chattering
        ev(59.0, "raise", "not_equalizing", 1), ev(62.0, "clear", "not_equalizing", 1),
        ev(51.0, "raise", "deviation", 2), ev(58.0, "clear", "deviation", 2),        # true: not counted
        ev(80.0, "raise", "deviation", 3), ev(82.0, "clear", "deviation", 3),        # rope 4 within: counts
        ev(131.0, "raise", "silent"),                                                # after the last frame
    ]
    fig = M.healthy_alarm_figures(events, (13.0, 110.0), float(times[-1]), times, beyond)
    assert fig["standing"] == ["deviation_possible:n1:r0"]
    assert fig["chattering"] == ["not_equalizing:n1:r1"]
    assert fig["raised"] == 5
    assert fig["kinds"] == {"deviation_possible": 1, "not_equalizing": 3, "deviation": 1}
    assert fig["excluded"] == {"rope truly beyond the limit": 1, "node silent after the wind": 1}
    # an alarm present for less than 90 % of the wind does not stand; twice a minute is no chatter
    fig = M.healthy_alarm_figures([ev(30.0, "raise", "oil_loss"), ev(0.0, "raise", "stroke_limit", 0),
                                   ev(20.0, "clear", "stroke_limit", 0), ev(50.0, "raise", "stroke_limit", 0)],
                                  (13.0, 110.0), 130.0)
    assert fig["standing"] == [] and fig["chattering"] == [] and fig["raised"] == 3


def test_the_node_silent_during_the_wind_counts():
    fig = M.healthy_alarm_figures([ev(40.0, "raise", "silent"), ev(46.0, "clear", "silent")], (13.0, 110.0), 130.0)
    assert fig["raised"] == 1 and fig["excluded"] == {}


def test_a_fault_alarmed_in_time_late_on_the_wrong_rope_and_not_at_all():
    kinds = ("stroke_limit",)
    # the piston enters its margin at 40.0 s: raised at 40.6 s on its rope: in time (1 s)
    fig = M.fault_alarm_figures([ev(40.6, "raise", "stroke_limit", 1)], kinds, 1, 0.0, 40.0, 41.0)
    assert fig["alarmed"] and fig["in_time"] and fig["latency_s"] == pytest.approx(0.6)
    # raised 2.5 s after: late
    fig = M.fault_alarm_figures([ev(42.5, "raise", "stroke_limit", 1)], kinds, 1, 0.0, 40.0, 41.0)
    assert fig["alarmed"] and not fig["in_time"] and fig["latency_s"] == pytest.approx(2.5)
    # raised on rope 3 only: the wrong rope
    fig = M.fault_alarm_figures([ev(40.5, "raise", "stroke_limit", 2), ev(41.0, "raise", "deviation", 1)],
                                kinds, 1, 0.0, 40.0, 41.0)
    assert not fig["alarmed"] and fig["wrong_rope"] == [2] and fig["latency_s"] is None
    assert fig["any_on_rope"] == {"kind": "deviation", "t_s": 41.0}      # what the legacy station would show
    assert fig["raised"] == {"stroke_limit": 1, "deviation": 1}
    # nothing of the kind: missed; an alarm before the fault's onset does not answer it
    fig = M.fault_alarm_figures([ev(5.0, "raise", "not_equalizing", 1), ev(6.0, "clear", "not_equalizing", 1)],
                                ("not_equalizing",), 1, 30.0, 93.6, 109.4)
    assert not fig["alarmed"] and fig["wrong_rope"] == [] and fig["raised"] == {}
    # a node's alarm (oil loss, rope None) on any rope
    fig = M.fault_alarm_figures([ev(60.0, "raise", "oil_loss")], ("oil_loss",), None, 5.0, 5.0, 128.0)
    assert fig["alarmed"] and fig["in_time"] and fig["latency_s"] == pytest.approx(55.0)


def test_silent_ropes_split_by_the_hidden_imbalance():
    times = np.arange(1, 601) * 0.1
    d = np.zeros((600, 4))
    d[100:140, 0] = 0.12     # rope 1: 12 % for 4 s, the seals may hide 15 %: within
    d[300:340, 1] = 0.20     # rope 2: 20 % for 4 s: beyond
    d[400:410, 2] = 0.30     # rope 3: 1 s only: no episode
    d[500:540, 3] = 0.25     # rope 4: covered by its stroke limit alarm
    hidden = np.full(600, 0.15)
    events = [ev(53.5, "raise", "stroke_limit", 3), ev(60.0, "clear", "stroke_limit", 3),
              ev(31.0, "raise", "rope_adjust", 1)]          # an advisory covers nothing
    out = M.silent_ropes(events, times, d, hidden)
    assert out["episodes"] == 3
    assert [e["rope"] for e in out["within_hidden"]] == [1] and [e["rope"] for e in out["beyond_hidden"]] == [2]
    assert out["beyond_hidden"][0]["true_max_pct"] == 20.0 and out["within_hidden"][0]["hidden_pct"] == 15.0
    # a DEVIATION on rope 2 during its episode: no longer silent; without hidden figures: unsplit
    out = M.silent_ropes(events + [ev(33.0, "raise", "deviation", 1)], times, d, None)
    assert [e["rope"] for e in out["unsplit"]] == [1] and not out["beyond_hidden"]
    # frames in a shock's hold do not count toward an episode
    valid = np.ones(600, bool)
    valid[310:330] = False
    out = M.silent_ropes(events, times, d, hidden, valid)
    assert [e["rope"] for e in out["beyond_hidden"]] == []
