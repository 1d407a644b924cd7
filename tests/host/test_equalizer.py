"""The equalizer's alarms on hand-built streams of version-3 frames (ropemon.station.equalizer and
the engine): stroke_limit (and its timing bound), not_equalizing (seized seal, closed valve,
blocked hose), oil_loss, rope_adjust and adjust_forecast; none on healthy streams with noise;
the lifecycle on a new kind; version-2 frames; the legacy baseline."""
from __future__ import annotations

import dataclasses
import math
import random

import pytest

from ropemon.station.alarms import AlarmEngine, AlarmSettings, PRIORITY, WARNING_KINDS
from ropemon.station.equalizer import (EqualizerSettings, EqualizingTracker, adjust_forecast, positions,
                                       stroke_check)
from ropemon.station.protocol import Frame, L, Rope

DT = 0.1                 # frames at 10 Hz
AREA = 7.85e-3           # m^2: the paper site's 100 mm bore
K = 3e-10                # m/Pa: 0.3 um/kPa
EQ = EqualizerSettings(areas_m2=(AREA,) * 4, stroke_m=(0.2,) * 4, margin_m=0.01, compliance_m_per_pa=(K,) * 4)
EQ_LAG = dataclasses.replace(EQ, position_lag=True)   # a lagging piston alone raises (off by default)
NEW_KINDS = ("stroke_limit", "not_equalizing", "oil_loss", "rope_adjust")


def rope(kpa, pos_m, tension_dan=None):
    t = round(kpa * AREA * 100) if tension_dan is None else tension_dan   # kPa * m^2 * 1000 / 10 daN
    pos = L.POS_ABSENT if pos_m is None else round(pos_m * 1e4)
    return Rope(t, t, t, round(kpa), pos)


def frame(kpas, xs, seq, node=1, fault_mask=0, stroke_mask=0, speed_mm_s=0, oil_temp_cc=L.OIL_TEMP_ABSENT,
          version=3, status=0, depth_mm=0):
    recs = tuple(rope(p, x) for p, x in zip(kpas, xs))
    if version == 2:
        recs = tuple(r._replace(pos_01mm=L.POS_ABSENT) for r in recs)
    return Frame(version, 0, node, fault_mask, seq, round(seq * DT * 1000), status, recs, depth_mm, speed_mm_s, 7400,
                 oil_temp_cc, stroke_mask=stroke_mask if version >= 3 else 0)


def engine(eq=EQ, **kw):
    return AlarmEngine(AlarmSettings(equalizer=eq, stuck_s=None, **kw))


class Stream:
    """Frames at DT into an engine; `events` of the new kinds."""

    def __init__(self, eng=None, seed=1, noise_m=2e-5 / math.sqrt(20), noise_kpa=1.1):
        self.eng, self.seq, self.events = eng or engine(), 0, []
        self.rng = random.Random(seed)
        self.noise_m, self.noise_kpa = noise_m, noise_kpa

    @property
    def t(self) -> float:
        return self.seq * DT

    def feed(self, kpas, xs, n=1, noisy=True, **kw):
        for _ in range(n):
            p = [k + (self.rng.gauss(0, self.noise_kpa) if noisy else 0.0) for k in kpas]
            x = [None if v is None else v + (self.rng.gauss(0, self.noise_m) if noisy else 0.0) for v in xs]
            self.events += [e for e in self.eng.update(frame(p, x, self.seq, **kw), self.t) if e.kind in NEW_KINDS]
            self.seq += 1
        return self

    def raised(self):
        return [(e.alarm, round(e.time_s, 1)) for e in self.events if e.action == "raise"]

    def present(self):
        return sorted(a.id for a in self.eng.active() if a.present)


def hoist(stream, p0, p1, secs, a=(0.0, 0.0, 0.0, 0.0), rule=None, **kw):
    """A load change: every pressure from p0 to p1 kPa over `secs`; piston i at a_i + k p
    (the oil's compression), or `rule(i, p, x_healthy) -> (kpa, x)` for a faulty rope."""
    n = max(1, round(secs / DT))
    for j in range(n + 1):
        p = p0 + (p1 - p0) * j / n
        kpas, xs = [], []
        for i in range(4):
            x = a[i] + K * p * 1000.0
            kp = p
            if rule is not None:
                kp, x = rule(i, p, x)
            kpas.append(kp)
            xs.append(x)
        stream.feed(kpas, xs, **kw)
    return stream


# ---------------------------------------------------------------- stroke limit


def test_stroke_limit_raises_on_the_first_frame_in_the_margin_and_clears_with_hysteresis():
    s = Stream()
    a = [0.0, 0.080, 0.0, 0.0]
    for k in range(15):                   # rope 2 sliding out 1 mm per frame, the others back by its oil
        a = [-0.001 * k / 3, 0.080 + 0.001 * k, -0.001 * k / 3, -0.001 * k / 3]
        s.feed([3000] * 4, [v + K * 3e6 for v in a], noisy=False)
    first = next(k for k in range(15) if 0.080 + 0.001 * k + K * 3e6 >= 0.090)
    assert s.raised() == [("stroke_limit:n1:r1", round(first * DT, 1))]
    ev = s.events[0]
    assert ev.rope == 1 and ev.value >= 90.0 and ev.threshold == 90.0
    assert "rope 2 piston at its extended end" in ev.message and "from mid-stroke" in ev.message
    assert "deviation can no longer be ruled out" in ev.message and "stop winding people" in ev.message
    assert "lengthen" in ev.message and PRIORITY["stroke_limit"] == 1
    # back to 89 mm (out of the margin, inside the hysteresis): it stays; at 85 mm it clears after 2 s
    o = a[0]
    s.feed([3000] * 4, [o, 0.089, o, o], n=40, noisy=False)
    assert s.present() == ["stroke_limit:n1:r1"]
    s.feed([3000] * 4, [o, 0.085, o, o], n=19, noisy=False)
    assert s.present() == ["stroke_limit:n1:r1"]
    s.feed([3000] * 4, [o, 0.085, o, o], n=3, noisy=False)
    assert s.present() == [] and [e.action for e in s.events] == ["raise", "clear"]


def test_the_retracted_end_and_the_nodes_mask_alone():
    """Without the stroke in the config the node's mask (it checks every sample) raises it; the
    retracted end's message says to shorten the rope."""
    s = Stream(engine(EqualizerSettings()))
    s.feed([3000] * 4, [0.0, 0.0, -0.05, 0.0], n=5)
    assert s.events == []
    s.feed([3000] * 4, [0.0, 0.0, -0.05, 0.0], n=2, stroke_mask=1 << 2)     # bit i: retracted end of rope i
    assert s.raised() == [("stroke_limit:n1:r2", 0.5)]
    assert "retracted end" in s.events[0].message and "shorten" in s.events[0].message
    assert "the node's stroke flag" in s.events[0].message
    s.feed([3000] * 4, [0.0, 0.0, -0.05, 0.0], n=25)
    assert [e.action for e in s.events] == ["raise", "clear"]


def test_a_failed_transmitter_never_raises_a_stroke_limit():
    """A displacement fault (fault_mask bit 4+i) or no position: the rope is not judged, SENSOR FAULT
    names it; a raised stroke alarm is suppressed by design meanwhile."""
    eng = engine()
    for k in range(10):
        eng.update(frame([3000] * 4, [0.095, 0.0, 0.0, 0.0], k, fault_mask=1 << 4, stroke_mask=1 << 4), k * DT)
        eng.update(frame([3000] * 4, [0.0, None, 0.0, 0.0], 100 + k, node=2, stroke_mask=1 << 5), k * DT)
    kinds = {(a.kind, a.node) for a in eng.active()}
    assert ("sensor_fault", 1) in kinds and not any(k == "stroke_limit" for k, _ in kinds)
    assert "displacement of rope 1" in next(a.message for a in eng.active() if a.kind == "sensor_fault")
    assert stroke_check(frame([0] * 4, [0.095, None, 0.0, 0.0], 0, fault_mask=1 << 4), EQ)[:2] == [None, None]
    # raised, then the channel fails: hidden (suppressed), back when the channel is healthy
    eng = engine()
    for k in range(3):
        eng.update(frame([3000] * 4, [0.095, 0.0, 0.0, 0.0], k), k * DT)
    assert [a.id for a in eng.active() if a.kind == "stroke_limit"] == ["stroke_limit:n1:r0"]
    eng.update(frame([3000] * 4, [0.095, 0.0, 0.0, 0.0], 3, fault_mask=1 << 4), 0.3)
    assert not any(a.kind == "stroke_limit" for a in eng.active())
    assert [a.state for a in eng.hidden() if a.kind == "stroke_limit"] == ["suppressed"]


@pytest.mark.parametrize("seed", range(20))
def test_stroke_limit_within_one_second_of_the_first_frame_in_the_margin(seed):
    """A piston running into its margin at a random speed and phase, with noise: the alarm is raised
    at most 1 s after the first frame whose window had the piston in the margin (by its mask or its
    mean position); here at that frame (the frames at 10 Hz, the raise on the first)."""
    rng = random.Random(seed)
    v = rng.uniform(0.2e-3, 20e-3)                 # m/s towards the extended end
    x0 = 0.09 - rng.uniform(0.5, 5.0) * v          # reaches the margin within 0.5-5 s
    end = 0.09
    s = Stream(seed=seed)
    first = None
    for k in range(100):
        lo, hi = x0 + v * k * DT, x0 + v * (k + 1) * DT            # the window's samples span this
        mask = (1 << 5) if hi >= end else 0                        # the node: any sample in the margin
        if mask and first is None:
            first = s.t
        s.feed([3000] * 4, [0.0, (lo + hi) / 2, 0.0, 0.0], stroke_mask=mask)
    (raised,) = [t for aid, t in s.raised() if aid == "stroke_limit:n1:r1"]
    assert first is not None and raised - first <= 1.0 + 1e-9 and raised - first <= DT + 1e-9


# ---------------------------------------------------------------- not equalizing


def seized(rope_i, x_held):
    return lambda i, p, x: (p, x_held if i == rope_i else x)


def test_a_seized_seal_raises_within_the_load_change_and_names_it():
    """The others' pistons move 0.3 um/kPa with the pressure (1.2 mm over a 4 MPa loading): the
    seized piston's lag shows past the tolerance (0.26 mm) and is confirmed once their motion has
    doubled (0.53 mm, 1.8 MPa), within the loading (with `position_lag`)."""
    s = Stream(engine(EQ_LAG))
    s.feed([2500] * 4, [K * 2.5e6] * 4, n=30)
    hoist(s, 2500, 6500, 8.0, rule=seized(1, K * 2.5e6))             # a 4 MPa loading over 8 s
    (r,) = [e for e in s.events if e.action == "raise"]
    assert r.alarm == "not_equalizing:n1:r1" and 3.0 < r.time_s < 3.0 + 8.0
    assert "seized seal" in r.message and "rope 2 not equalizing" in r.message
    assert "deviation can no longer be ruled out" in r.message and "stop winding people" in r.message
    assert "its piston did not move" in r.message and r.value <= 0.3    # 0.1 mm steps: +-1 step
    # the seal freed (repaired): in the next load change its piston moves with the others: cleared
    s.feed([6500] * 4, [K * 6.5e6] * 4, n=3010)                      # a rest longer than anchor_max_s
    hoist(s, 6500, 2500, 8.0)
    assert [e.action for e in s.events] == ["raise", "clear"]


def test_by_default_a_piston_that_stays_while_its_pressure_follows_raises_nothing():
    """A healthy seal at rest holds its piston through a load change as a seized one does (the
    simulated healthy winds: a piston still within 0.1 mm while the others move 3 mm): without
    `position_lag` only a departing pressure raises NOT EQUALIZING; the tracker still sees the lag."""
    s = Stream()
    s.feed([2500] * 4, [K * 2.5e6] * 4, n=30)
    hoist(s, 2500, 6500, 8.0, rule=seized(1, K * 2.5e6))
    assert s.events == []
    tr = EqualizingTracker(EQ)
    tr.update(frame([2500] * 4, [0.0] * 4, 0), 0.0)
    for k in range(1, 4):
        out = tr.update(frame([2500 + 1000 * k] * 4, [3e-4 * k, 3e-4 * k, 0.0, 3e-4 * k], k), 0.1 * k)
    assert not out[2].lags and out[0].follows and out[2].ratio == pytest.approx(0.0)


def test_a_balancing_stroke_whose_flow_parts_the_pressures_is_not_a_cut_off_cylinder():
    """As on a simulated healthy wind: pistons sliding against each other (+0.8 mm one, -0.6 mm the
    others) while the taps' pressures part by 40-60 kPa with the flow. A cut-off cylinder's piston
    moves only by its own oil's compression (k x 50 kPa: 15 um): these slid, nothing raises."""
    s = Stream().feed([2500] * 4, [K * 2.5e6] * 4, n=30)
    for k in range(41):
        f = k / 40
        kpas = [2500 - 57 * f, 2500 + 46 * f, 2500 + 10 * f, 2500 + 20 * f]
        xs = [K * 2.5e6 + 0.8e-3 * f] + [K * 2.5e6 - 0.6e-3 * f] * 3
        s.feed(kpas, xs)
    s.feed([2443, 2546, 2510, 2520], [K * 2.5e6 + 0.8e-3] + [K * 2.5e6 - 0.6e-3] * 3, n=30)
    assert s.events == []


def test_a_slow_balancing_stroke_under_the_tolerance_whose_flow_parts_two_taps_raises_nothing():
    """As on a simulated healthy wind (cold oil): one piston slides +0.2 mm and another -0.2 mm over
    3 s, under the motion tolerance (0.26 mm), while their flow parts the two taps by +107 and -73
    kPa and the others' pressures stay. A cut-off cylinder's piston moves no more than its own oil's
    compression (k x 107 kPa: 32 um) give or take the frame's resolution (0.12 mm): these slid
    farther, so they share the manifold's oil; nothing raises. The same departure with the pistons
    still is a cut-off cylinder (and raises: the test below)."""
    x0 = K * 2.5e6
    s = Stream().feed([2500] * 4, [x0] * 4, n=30)
    for k in range(31):
        f = k / 30
        s.feed([2500 + 107 * f, 2500 - 73 * f, 2500, 2500], [x0 + 0.2e-3 * f, x0 - 0.2e-3 * f, x0, x0])
    s.feed([2607, 2427, 2500, 2500], [x0 + 0.2e-3, x0 - 0.2e-3, x0, x0], n=20)
    assert s.events == []
    s = Stream().feed([2500] * 4, [x0] * 4, n=30)
    for k in range(31):
        s.feed([2500 + 107 * k / 30, 2500, 2500, 2500], [x0] * 4)
    s.feed([2607, 2500, 2500, 2500], [x0] * 4, n=20)
    assert [e.alarm for e in s.events if e.action == "raise"] == ["not_equalizing:n1:r0"]
    # the valve opened again: its tap with the others', and in the next loading its piston moves
    # with theirs: cleared
    s.feed([2500] * 4, [x0] * 4, n=20)
    hoist(s, 2500, 6500, 8.0)
    assert [(e.alarm, e.action) for e in s.events] == [("not_equalizing:n1:r0", "raise"),
                                                       ("not_equalizing:n1:r0", "clear")]


def test_the_others_medians_sorted_once_are_the_medians_of_each_left_out():
    """`_medians_without` (one sort per frame) gives what `_median_without` gives rope by rope,
    ties and all, for two to six ropes."""
    from ropemon.station.equalizer import _median_without, _medians_without
    rng = random.Random(3)
    for n in range(2, 7):
        for _ in range(300):
            vals = [float(rng.choice([-2, -1, 0, 0, 1, 3])) + rng.choice([0.0, 0.5]) for _ in range(n)]
            assert _medians_without(vals) == [_median_without(sorted(vals), x) for x in vals], vals


def test_a_closed_valve_towards_the_manifold_departs_in_pressure():
    """The tap reads the cut-off cylinder: its pressure departs from the others' while its piston
    moves only by its own oil's compression."""
    def rule(i, p, x):
        if i != 2:
            return p, x
        own = 2500 + (p - 2500) * 1.4
        return own, K * 2.5e6 + 0.25 * K * (own - 2500) * 1000.0
    s = Stream().feed([2500] * 4, [K * 2.5e6] * 4, n=30)
    hoist(s, 2500, 6500, 10.0, rule=rule)
    (r,) = [e for e in s.events if e.action == "raise"]
    assert r.alarm == "not_equalizing:n1:r2"
    assert "stop valve closed between its pressure tap and the manifold" in r.message
    assert "its pressure departs" in r.message


def test_a_departure_after_a_long_wind_is_judged_against_the_change_since_a_still_frame():
    """The ropes' pressure climbs 4 MPa over a minute's wind while the pistons stay (stiff oil), then
    rope 3's valve closes and a 0.4 MPa stop follows: its tap departs 150 kPa, 37 % of that change
    but under 5 % of the 4.4 MPa since the wind's start. The reference taken again on a still frame
    judges it within the stop; one kept from the start of the wind would not."""
    x0 = 0.72e-3   # off the frame's 0.1 mm rounding edges

    def run(eq):
        def held(i, p, x):
            return p, x0
        s = Stream(engine(eq)).feed([2500] * 4, [x0] * 4, n=30)
        hoist(s, 2500, 6500, 60.0, rule=held)
        s.feed([6500] * 4, [x0] * 4, n=30)
        t_stop = s.t

        def shut(i, p, x):
            return (6500 + (p - 6500) * 0.625 if i == 2 else p), x0
        hoist(s, 6500, 6900, 1.0, rule=shut)
        s.feed([6900, 6900, 6750, 6900], [x0] * 4, n=40)
        return s, t_stop

    s, t_stop = run(EQ)
    (r,) = [e for e in s.events if e.action == "raise"]
    assert r.alarm == "not_equalizing:n1:r2" and r.time_s <= t_stop + 1.0 + 2.5, (r.time_s, t_stop)
    assert "its pressure departs" in r.message
    stale, _ = run(dataclasses.replace(EQ, quiet_anchor_s=1e9))
    assert not [e for e in stale.events if e.action == "raise"]


def test_a_blocked_hose_follows_in_pressure_but_its_piston_does_not_share_the_oil():
    def rule(i, p, x):
        return (p, K * 2.5e6 + 0.3 * K * (p - 2500) * 1000.0) if i == 0 else (p, x)
    s = Stream(engine(EQ_LAG)).feed([2500] * 4, [K * 2.5e6] * 4, n=30)
    hoist(s, 2500, 6500, 10.0, rule=rule)
    (r,) = [e for e in s.events if e.action == "raise"]
    assert r.alarm == "not_equalizing:n1:r0"
    assert "blocked hose" in r.message and "pressure followed" in r.message and "seized" not in r.message


def test_a_cut_off_cylinder_whose_piston_follows_departs_in_pressure_within_the_loading():
    """As the simulated closed valve (manifold side) does: the cut-off cylinder's own oil compresses
    almost as the others' (its piston moves 80 % of theirs, within the tolerance), but its pressure
    departs, 25 % more than the others' change: raised within the loading, naming the valve or a
    misreading transmitter."""
    def rule(i, p, x):
        if i != 1:
            return p, x
        own = 2500 + (p - 2500) * 1.25
        return own, 0.8 * K * own * 1000.0 + 0.2 * K * 2.5e6
    s = Stream().feed([2500] * 4, [K * 2.5e6] * 4, n=30)
    hoist(s, 2500, 2800, 6.0, rule=rule)                              # a 0.3 MPa loading over 6 s
    (r,) = [e for e in s.events if e.action == "raise"]
    assert r.alarm == "not_equalizing:n1:r1" and r.time_s <= 3.0 + 6.0 + 0.1
    assert "cut off from the manifold" in r.message and "transmitter misreads" in r.message


def test_a_flow_transient_in_the_reference_frame_is_not_a_departure():
    """A tap reading 50 kPa off the others for one frame (the flow of a slide, as on the simulated
    healthy winds) when the tracker takes its reference: the reference's offsets are the median of
    the last frames', so the unloading that follows, alike on every tap, departs nowhere."""
    tr = EqualizingTracker(dataclasses.replace(EQ, anchor_max_s=0.45))
    x = [K * 7.5e6] * 4
    for k in range(5):
        tr.update(frame([7500] * 4, x, k), 0.1 * k)
    tr.update(frame([7500, 7450, 7500, 7500], x, 5), 0.5)      # the reference moves on here
    for k in range(6, 20):
        p = 7500 - 25 * (k - 5)
        out = tr.update(frame([p] * 4, [K * p * 1000] * 4, k), 0.1 * k)
        assert not any(o.lags for o in out), k


def test_a_reference_taken_within_a_slip_does_not_make_the_taps_return_a_departure():
    """As on a simulated healthy wind at the pithead: the tracker's reference falls within a slip
    (rope 2's piston -0.3 mm, rope 3's +0.3 mm in 0.3 s, its flow parting their taps by -200 and
    +150 kPa); once the pistons are still the taps read the manifold's pressure again. The
    reference's offsets are those of the last frames where the pistons moved alike, so nothing
    departs; the pressure then rises alike on every tap (the payload landing) and nothing raises."""
    tr = EqualizingTracker(dataclasses.replace(EQ, anchor_max_s=2.25))
    x = [K * 6.5e6] * 4
    k = 0
    for k in range(20):                                            # 2 s at rest
        tr.update(frame([6500] * 4, x, k), 0.1 * k)
    for j, (d, dp2, dp3) in enumerate(((-1e-4, -200, 150), (-2e-4, -190, 140), (-3e-4, -120, 90))):
        k += 1
        xs = [x[0], x[1] + d, x[2] - d, x[3]]
        tr.update(frame([6500, 6500 + dp2, 6500 + dp3, 6500], xs, k), 0.1 * k)   # the reference moves on here
    for j in range(60):                                            # still, then the taps rise alike
        k += 1
        p = 6500 + 10 * max(0, j - 20)
        out = tr.update(frame([p] * 4, [x[0], x[1] - 3e-4, x[2] + 3e-4, x[3]], k), 0.1 * k)
        assert not any(o.lags for o in out), (k, out)


def test_no_evidence_of_following_while_oil_flows_between_the_others():
    """A rope raised as cut off clears only on frames whose taps it could be judged on: while two
    of the others slide against each other (their flow parts the taps), its piston moving with
    their median is no evidence; once they have moved alike for a second, it is."""
    tr = EqualizingTracker(EQ)
    k = 0
    for k in range(20):
        tr.update(frame([2500] * 4, [0.0] * 4, k), 0.1 * k)
    for j in range(1, 11):                                         # all +0.5 mm; ropes 3 and 4 part
        k += 1
        d = 0.4e-3 * j / 10
        out = tr.update(frame([2500 + 50 * j] * 4, [0.5e-3 * j / 10] * 2 + [0.5e-3 * j / 10 + d,
                                                                          0.5e-3 * j / 10 - d], k), 0.1 * k)
    assert not out[0].lags and not out[0].follows and out[0].own_m == pytest.approx(0.5e-3)
    for j in range(12):                                            # then all alike for 1.2 s
        k += 1
        out = tr.update(frame([3000 + 50 * j] * 4, [0.5e-3 + 0.2e-3 * j / 11] * 2 + [
            0.9e-3 + 0.2e-3 * j / 11, 0.1e-3 + 0.2e-3 * j / 11], k), 0.1 * k)
    assert out[0].follows


def test_a_frozen_transmitter_is_not_a_cut_off_cylinder():
    """Its pressure still while the others' move, its piston with theirs: SENSOR STUCK's, not this."""
    s = Stream().feed([2500] * 4, [K * 2.5e6] * 4, n=30)
    hoist(s, 2500, 4500, 8.0, rule=lambda i, p, x: (2500, x) if i == 3 else (p, x))
    assert s.events == []


def test_nobody_is_judged_while_a_piston_is_at_its_end():
    """A piston at its end stop takes no oil: the others' pressures and pistons part. STROKE LIMIT
    names it; no rope is judged for equalizing meanwhile."""
    s = Stream().feed([2500] * 4, [K * 2.5e6, K * 2.5e6, 0.095, K * 2.5e6], n=30)
    def rule(i, p, x):
        return (p, 0.095) if i == 2 else ((p + 100, x * 0.2) if i == 0 else (p, x))
    hoist(s, 2500, 6500, 8.0, rule=rule)
    assert [e.alarm for e in s.events if e.action == "raise"] == ["stroke_limit:n1:r2"]


@pytest.mark.parametrize("seed", range(6))
def test_healthy_hoists_with_noise_raise_none_of_the_new_alarms(seed):
    """Loadings, winds and unloadings with the displacement channel's noise (20 um rms per sample,
    frame means of 20 samples), the frame's 0.1 mm positions and 1 kPa pressures, pistons off
    mid-stroke, balancing strokes (one piston 1-5 mm one way, the others a third of it back: the
    oil kept) after a load change, against it or during it, and rests: nothing of the equalizer raises."""
    rng = random.Random(seed)
    s = Stream(seed=seed)
    a = [rng.uniform(-0.03, 0.03) for _ in range(4)]
    p = 2500.0
    for wind in range(6):
        s.feed([p] * 4, [ai + K * p * 1000 for ai in a], n=rng.randint(20, 60))
        p1 = rng.uniform(2000, 9000)
        hoist(s, p, p1, rng.uniform(3, 60), a=tuple(a), speed_mm_s=rng.choice([0, 3000, -8000]))
        p = p1
        j = rng.randrange(4)                                       # a balancing stroke
        d = rng.choice([-1, 1]) * rng.uniform(1e-3, 5e-3)
        for step in range(20):
            b = list(a)
            b[j] += d * step / 19
            for i in range(4):
                if i != j:
                    b[i] -= d / 3 * step / 19
            s.feed([p] * 4, [bi + K * p * 1000 for bi in b])
        a = b
    assert s.events == []
    assert not any(a.kind in NEW_KINDS for a in s.eng.active() + s.eng.hidden())


@pytest.mark.parametrize("seed", range(10))
def test_healthy_strokes_during_load_changes_raise_nothing(seed):
    """A balancing stroke (0.3-5 mm, over 0.3-3 s) at a random moment of each load change, either
    way: a stroke against the oil's motion leaves the stroke piston behind by a fixed amount,
    which the growing motion outgrows before the lag is confirmed."""
    rng = random.Random(seed)
    s = Stream(seed=seed)
    a = [rng.uniform(-0.03, 0.03) for _ in range(4)]
    p = 2500.0
    for wind in range(8):
        s.feed([p] * 4, [ai + K * p * 1000 for ai in a], n=rng.randint(20, 60))
        p1 = rng.uniform(2000, 9000)
        n = max(1, round(rng.uniform(3, 60) / DT))
        j, d = rng.randrange(4), rng.choice([-1, 1]) * rng.uniform(0.3e-3, 5e-3)
        start, length = rng.randrange(n), rng.randint(3, 30)
        for k in range(n + 1):
            pk = p + (p1 - p) * k / n
            f = min(1.0, max(0.0, (k - start) / length))
            b = [ai - d / 3 * f for ai in a]
            b[j] = a[j] + d * f
            s.feed([pk] * 4, [bi + K * pk * 1000 for bi in b])
        a, p = b, p1
    assert s.events == []


@pytest.mark.parametrize("held", [(0, 1, 3), (0, 1)])
def test_pistons_held_by_their_seals_while_others_slide_are_not_lagging(held):
    """As on the simulated duty cycle: in a wind's pressure fall three pistons stand, held by their
    seals, while one slides with all the oil's motion (or two and two): none is the odd one out."""
    s = Stream()
    s.feed([5200] * 4, [K * 5.2e6] * 4, n=30)
    slide = [i for i in range(4) if i not in held]
    x_held = K * 5.2e6
    for k in range(150):                       # 15 s, 1.5 MPa down
        p = 5200 - 10 * k
        drop = K * (5.2e6 - p * 1000.0) * 4 / len(slide)   # the sliding pistons take all the motion
        s.feed([p] * 4, [x_held if i in held else K * 5.2e6 - drop for i in range(4)])
    assert s.events == []


def test_the_tracker_judges_against_the_others_and_skips_a_rope_at_its_end():
    tr = EqualizingTracker(EQ_LAG)
    tr.update(frame([2500] * 4, [0.0] * 4, 0), 0.0)
    out = tr.update(frame([3500] * 4, [3e-4, 3e-4, 0.0, 3e-4], 1), 0.1)
    assert not out[2].lags and out[0].follows          # lagging, not yet while the others' motion doubled
    out = tr.update(frame([4500] * 4, [6e-4, 6e-4, 0.0, 6e-4], 2), 0.2)
    assert out[2].lags and not out[0].lags and out[0].follows and out[2].ratio == pytest.approx(0.0)
    out = tr.update(frame([4500] * 4, [6e-4, 6e-4, 0.0, 6e-4], 3), 0.3, skip=[False, False, True, False])
    assert not out[2].lags
    # a piston that slid against the others (a balancing stroke) is equalizing, not lagging
    tr = EqualizingTracker(EQ)
    tr.update(frame([2500] * 4, [0.0] * 4, 0), 0.0)
    for k, x0 in enumerate((-2e-4, -1e-3, -1e-3)):
        out = tr.update(frame([2500 + 1000 * (k + 1)] * 4, [x0 + 3e-4 * (k + 1)] + [3e-4 * (k + 1)] * 3, k + 1),
                        0.1 * (k + 1))
    assert not any(o.lags for o in out)
    assert EQ.motion_tolerance_m == pytest.approx(2e-4 + 10 * 2e-5 / math.sqrt(20) * math.sqrt(2))


# ---------------------------------------------------------------- oil loss


def test_oil_loss_of_a_tenth_of_a_litre_a_minute_raises_within_the_wind_with_its_rate():
    """0.1 L/min from t = 30 s through a wind (pressure 2.5 -> 5.5 MPa: 0.9 mm of compression per
    piston, 28 mL in all, which the compliance explains): raised, its rate in the message."""
    s = Stream()
    leak = 0.1e-3 / 60                                            # m^3/s
    onset = 30.0
    for k in range(1200):
        t = k * DT
        p = 2500 + 3000 * min(1.0, max(0.0, (t - 10) / 90))
        lost = max(0.0, t - onset) * leak
        x = K * p * 1000 + lost / (4 * AREA)                     # the oil lost pulls the pistons out
        s.feed([p] * 4, [x] * 4)
    raises = [e for e in s.events if e.action == "raise"]
    assert [e.alarm for e in raises] == ["oil_loss:n1"]
    r = raises[0]
    assert r.time_s - onset < 60.0 and PRIORITY["oil_loss"] == 2
    (a,) = [a for a in s.eng.active() if a.kind == "oil_loss"]
    rate = float(a.message.split("(")[1].split(" L/min")[0])
    assert rate == pytest.approx(0.1, abs=0.02)
    assert "find the leak and refill" in a.message
    # the leak stopped: the window's loss falls under half the band and the alarm clears
    x_end = x
    s.feed([p] * 4, [x_end] * 4, n=1500)
    assert any(e.action == "clear" and e.kind == "oil_loss" for e in s.events)


def test_oil_balance_follows_compression_and_temperature():
    """Healthy: a 6 MPa load change (1.8 mm per piston: 57 mL of compression) and the oil warming
    by 5 K (the pistons drawn in by its expansion): no oil loss."""
    vol = 0.008
    eq = EqualizerSettings(areas_m2=(AREA,) * 4, stroke_m=(0.2,) * 4, margin_m=0.01, compliance_m_per_pa=(K,) * 4,
                           oil_volume_m3=vol)
    s = Stream(engine(eq))
    for k in range(1500):
        t = k * DT
        p = 2000 + 6000 * min(1.0, t / 60)
        temp = 15.0 + 5.0 * t / 150
        x = K * p * 1000 - 7e-4 * vol * (temp - 15.0) / (4 * AREA)
        s.feed([p] * 4, [x] * 4, oil_temp_cc=round(temp * 100))
    assert s.events == []
    st = s.eng._oil[1].last
    assert abs(st.balance_m3) < 3e-6
    # without the compliance the station does not judge the oil (the wind's compression alone is tens of mL)
    s = Stream(engine(EqualizerSettings(areas_m2=(AREA,) * 4)))
    for k in range(600):
        s.feed([2000 + 10 * k] * 4, [K * (2000 + 10 * k) * 1000] * 4)
    assert s.events == [] and s.eng.hoist_status(1) is None     # no band: None (a version 3 node)


# ---------------------------------------------------------------- rope adjustment


def test_adjust_forecast_trend_and_winds_left():
    rests = [[0.05 + 0.001 * w, 0.0, -0.05 - 0.0005 * w, None if w % 2 else 0.01] for w in range(10)]
    f = adjust_forecast(rests, 0.2, 0.01)
    assert f[0].trend_m == pytest.approx(0.001) and f[0].end == "extended"
    assert f[0].last_m == pytest.approx(0.059)
    assert f[0].winds_left == pytest.approx((0.09 - 0.059) / 0.001)
    assert f[1].winds_left is None and f[1].trend_m == pytest.approx(0.0)
    assert f[2].end == "retracted" and f[2].winds_left == pytest.approx((0.09 - 0.0545) / 0.0005)
    assert f[3].trend_m == pytest.approx(0.0)                      # the rests it has, the wind index kept
    assert adjust_forecast(rests[:2], 0.2, 0.01) == [None] * 4    # too few winds
    assert adjust_forecast([[0.095], [0.096], [0.097]], [0.2], 0.01)[0].winds_left == 0.0
    assert adjust_forecast([], 0.2, 0.01) == []
    with pytest.raises(ValueError, match="stroke_m"):
        adjust_forecast(rests, 0.0, 0.01)
    with pytest.raises(ValueError, match="margin_m"):
        adjust_forecast(rests, 0.2, -0.01)


def duty_cycle(s, winds, creep_m, x0):
    """Winds of 5 s at speed between the landings (808 m, 2 m), each rest of 6 s split by a loading
    (the cage moving a few mm/s for a second: two rests at one landing, one wind); rope i's rest
    position creeps creep_m[i] per wind (its piston's share of the rope's length change)."""
    x = list(x0)
    for w in range(winds):
        depth = 808_000 if w % 2 == 0 else 2_000
        s.feed([3000] * 4, [xi + K * 3e6 for xi in x], n=40, depth_mm=depth)
        s.feed([3000] * 4, [xi + K * 3e6 for xi in x], n=10, speed_mm_s=40, depth_mm=depth)   # loading
        s.feed([3000] * 4, [xi + K * 3e6 for xi in x], n=40, depth_mm=depth + 30)
        s.feed([3500] * 4, [xi + K * 3.5e6 for xi in x], n=50, speed_mm_s=8000, depth_mm=400_000)
        x = [xi + c for xi, c in zip(x, creep_m)]
    return x


def test_rope_adjust_advisory_at_least_five_winds_before_the_margin():
    s = Stream()
    creep = [0.8e-3, -0.8e-3 / 3, -0.8e-3 / 3, -0.8e-3 / 3]
    x0 = [0.060, 0.0, 0.0, 0.0]                 # rope 1 reaches its margin (90 mm) after ~36 winds
    duty_cycle(s, 45, creep, x0)
    r = next(e for e in s.events if e.action == "raise")
    assert r.alarm == "rope_adjust:n1:r0" and r.kind in WARNING_KINDS and PRIORITY["rope_adjust"] == 3
    wind_raised = int(r.time_s // 14.0)
    reaches = next(w for w in range(100) if x0[0] + K * 3.5e6 + 0.8e-3 * w >= 0.09)
    assert reaches - wind_raised >= 5
    assert "rope 1 needs adjusting" in r.message and "+0.80 mm per wind" in r.message
    assert "winds left" in r.message and "extended end" in r.message
    st = s.eng.hoist_status(1)
    assert st is None          # no band: the status is the band's; the forecast is the engine's
    fc = s.eng._forecast[1]
    assert fc[0].trend_m == pytest.approx(0.8e-3, rel=0.05)           # per wind: one rest per landing
    assert len(s.eng._rests[1].rests) == 20


def test_healthy_rests_give_no_advisory():
    s = Stream()
    duty_cycle(s, 30, [0.0] * 4, [0.02, -0.01, 0.0, 0.03])
    assert s.events == []


# ---------------------------------------------------------------- lifecycle, versions, baseline


def test_ack_and_shelve_a_stroke_limit():
    s = Stream()
    s.feed([3000] * 4, [0.0, 0.0, 0.0, 0.095], n=3)
    aid = "stroke_limit:n1:r3"
    (a,) = s.eng.active()
    assert a.id == aid and a.state == "unacknowledged" and a.priority == 1
    s.eng.ack(aid, s.t, "alice")
    assert s.eng.active()[0].state == "acknowledged" and s.eng.active()[0].acked_by == "alice"
    s.eng.shelve(aid, s.t, s.t + 60, "cylinder being refilled", "bob")
    assert s.eng.active() == [] and [h.state for h in s.eng.hidden()] == ["shelved"]
    s.feed([3000] * 4, [0.0, 0.0, 0.0, 0.095], n=5)                    # still evaluated, not annunciated
    assert s.eng.active() == []
    s.eng.unshelve(aid, s.t, "bob")
    assert s.eng.active()[0].state == "unacknowledged"               # still present: to be acknowledged


def test_version_2_frames_raise_none_and_the_status_says_so():
    from ropemon.station.uncertainty import BandParams
    band = BandParams.from_physical({"ropes": 4, "cylinder_area_m2": [AREA] * 4,
                                     "friction": {"Fs": {"intercept": 0.0, "slope": 600.0},
                                                  "Fc": {"intercept": 0.0, "slope": 400.0}}})
    s = Stream(engine(band=band))
    s.feed([3000] * 4, [0.095, 0.0, 0.0, 0.0], n=20, version=2)
    assert s.events == []
    st = s.eng.hoist_status(1)
    assert st.positions is False and "node 1 sends no piston positions (layout version 2)" in st.text
    assert st.hidden_frac is not None and st.hidden_frac > 0
    s.feed([3000] * 4, [0.095, 0.0, 0.0, 0.0], n=2)                   # the node upgraded
    assert s.raised() == [("stroke_limit:n1:r0", 2.0)] and s.eng.hoist_status(1).positions is True


def test_the_legacy_baseline_watches_no_pistons_and_keeps_deviation_possible():
    from ropemon.station.uncertainty import BandParams
    band = BandParams.from_physical({"ropes": 4, "cylinder_area_m2": [AREA] * 4,
                                     "friction": {"Fs": {"intercept": 0.0, "slope": 1000.0},
                                                  "Fc": {"intercept": 0.0, "slope": 600.0}}})
    eng = AlarmEngine(AlarmSettings(band=band, legacy_deviation_possible=True, equalizer=None))
    for k in range(20):
        eng.update(frame([5000] * 4, [0.095, 0.0, 0.0, 0.0], k), k * DT)
    assert sorted(a.kind for a in eng.active()) == ["deviation_possible"] * 4
    eng = AlarmEngine(AlarmSettings(band=band, equalizer=EQ))
    for k in range(20):
        eng.update(frame([5000] * 4, [0.095, 0.0, 0.0, 0.0], k), k * DT)
    assert sorted(a.kind for a in eng.active()) == ["stroke_limit"]


def test_settings_are_checked_and_wired_from_the_site():
    with pytest.raises(ValueError, match="equalizer.oil_band_m3"):
        EqualizerSettings(oil_band_m3=-1.0)
    with pytest.raises(ValueError, match="seized_ratio < lag_ratio"):
        EqualizerSettings(lag_ratio=0.9, follow_ratio=0.8)
    from ropemon.station.nodefigures import NodeFigures, alarm_settings
    site = NodeFigures(cylinder_area_m2=[AREA] * 4)
    site.stroke_m, site.stroke_margin_m = [0.2] * 4, 0.012
    eq = alarm_settings(site).equalizer
    assert eq.areas_m2 == (AREA,) * 4 and eq.stroke_m == (0.2,) * 4 and eq.margin_m == 0.012
    assert positions(frame([0] * 4, [0.01, None, -0.02, 0.0], 0, fault_mask=1 << 7)) == \
        [pytest.approx(0.01), None, pytest.approx(-0.02), None]


def test_a_cut_off_cylinders_pressure_does_not_make_the_others_look_stuck():
    """At rest, a cut-off cylinder's pressure still rises with its rope (300 kPa over 8 s) while the
    others' stand: the station judges SENSOR STUCK against the others' median, so the three standing
    transmitters are not stuck; the legacy station (the others' mean) took them for stuck."""
    def run(settings):
        eng = AlarmEngine(settings)
        kinds = set()
        for k in range(100):
            kpas = [4950, 4950 + min(300, 4 * k), 4950, 4950]
            for e in eng.update(frame(kpas, [0.01] * 4, k), k * DT):
                kinds.add((e.kind, e.rope))
        return kinds
    assert not any(k == "sensor_stuck" for k, _ in run(AlarmSettings(equalizer=EQ)))
    assert {("sensor_stuck", 0), ("sensor_stuck", 2), ("sensor_stuck", 3)} <= \
        run(AlarmSettings(legacy_deviation_possible=True, equalizer=None))
