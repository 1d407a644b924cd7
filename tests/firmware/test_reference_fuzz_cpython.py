"""Fixed-point node vs the float reference on fuzzed streams with a hydraulic compliance.

test_compensation_cpython.py holds the node within 0.05 % of rated of the reference on the
shipped config's random streams; here draws of compliance configs and streams with what
those lack: pressure steps of up to 10 MPa on every channel at once, held a sample or two
or repeated as a square wave near the rope bounce (within the NAMUR limits), which drive
the pressure tracker into the node's clamps (kernel.py: its bounce within +-2**26 of its
units, the creep and its rate within +-2**28), which the reference mirrors
(reference.PressureTracker). Steps of 5 and 10 MPa are beyond the pressure step check's
limit (1.16 MPa for these configs): both fault the same samples.

A balancing stroke starts and ends by comparing e and the common motion cl with
thresholds, and node and reference hold them a few hundredths of a um apart: where one
grazes its threshold they decide a sample or seconds apart. So the differential tests here
run the reference following the node's decisions (reference.Follow, `_follows`): where
the two decide apart, the reference's own rule on the node's values must give the node's
decision, and both must track strokes at the same samples (else it is a dispute and the
test fails); then they must take the same strokes and stay within 0.05 % of rated.

The stroke draws go down to `stroke_sigmas` 1 and `stroke_settle_s` 0, with two ropes'
pistons and compliances alike (their e tie within rounding: a stroke starts only when
exactly one rope's e is past the threshold); `make test` runs 96 draws, ROPEMON_STROKE_DRAWS=400 more. One case is held to 0.1 %
instead: the rest hold's switch amplifies rounding past 0.05 % for 80 ms.
"""
from __future__ import annotations

import os
import random

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from streams_cpython import random_stream, run_node, slide_stream

from ropemon.commission import reference
from ropemon.commission.nodejson import example_physical, make_node_json
from ropemon.lab.studies.stroke_events import node_trace
from ropemon.firmware import node_module

config = node_module("config")
Node = node_module("node").Node

EXAMPLES = int(os.environ.get("ROPEMON_FUZZ_EXAMPLES", "60"))


def _doc(k_m: list[float], sigma0: float, **changes) -> dict:
    ph = example_physical()
    ph.update(changes)
    ph["hydraulic_compliance_m_per_Pa"] = k_m
    ph["friction"] = dict(ph["friction"], sigma0=sigma0, sigma1=sigma0 * 1e-3)
    ph["piston_speed_max_m_s"] = 0.05  # sigma0 dx_max within the node's 2**19 (N/16)
    return make_node_json(ph)


def _steps(ph: dict, recs: np.ndarray, events: list, square: tuple | None) -> np.ndarray:
    """recs with every pressure channel stepped by mpa (+-) for `width` samples at each
    event, and optionally a square wave of +-amp/2 MPa at f Hz from t0 for `dur` s."""
    fs = ph["sample_hz"]
    r = recs.astype(np.int64)
    k = r.shape[0]
    for i in range(ph["ropes"]):
        pc = ph["pressure_channels"][i]
        c4, c20 = pc["counts_4mA"], pc["counts_20mA"]
        per_pa = (c20 - c4) / (pc["range_Pa"][1] - pc["range_Pa"][0])
        for at, width, mpa in events:
            j = int(at * (k - 3))
            r[j:j + width, i] += round(mpa * 1e6 * per_pa)
        if square is not None:
            f, t0, dur, amp = square
            t = np.arange(k) / fs
            on = (t >= t0) & (t < t0 + dur)
            sq = np.where(np.sin(2 * np.pi * f * (t - t0)) >= 0, 1, -1)
            mid = (c4 + c20) // 2
            r[on, i] = mid + sq[on] * round(amp * 0.5e6 * per_pa)
        r[:, i] = np.clip(r[:, i], c4, c20)  # inside NAMUR: a glitch the loop check passes
    return r.astype(np.uint16)


def _events(state: np.ndarray) -> list:
    """(sample, rope or -1) at each start and end of a stroke in a trace of (mode, ...)."""
    mode = state[:, 0]
    return [(int(j), int(mode[j]) - 1) for j in np.flatnonzero(mode != np.concatenate(([0], mode[:-1])))]


def _follows(doc: dict, recs: np.ndarray, limit_pct: float = 0.05):
    """(node trace, reference following it, its Follow) after checking what a follow must hold:
    no decision disputed (every decision the two take apart is the reference's own rule on
    the node's values, and both track strokes at the same samples), the same strokes and
    good samples, and the tensions within `limit_pct` % of rated."""
    ph = doc["physical"]
    tr = node_trace(doc, recs)
    follow = tr.follow()
    strokes: list = []
    ref = reference.compensate(ph, recs, strokes=strokes, follow=follow)
    assert follow.disputes == []
    assert _events(tr.state) == [(j, r) for j, r, _ in strokes]
    assert (tr.good == ref.good).all()
    err = np.abs(tr.tension - ref.tension_n)[tr.good]
    assert err.max() <= limit_pct / 100 * ph["rated_rope_tension_N"], err.max() / ph["rated_rope_tension_N"]
    return tr, ref, follow


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**16),
       k_m=st.lists(st.floats(1e-10, 6e-10), min_size=4, max_size=4),
       sigma0=st.sampled_from([1e7, 1e8]),
       events=st.lists(st.tuples(st.floats(0.1, 0.99), st.integers(1, 2),
                                 st.sampled_from([-10.0, -5.0, 5.0, 10.0])), max_size=4),
       square=st.none() | st.tuples(st.floats(0.5, 6.0), st.floats(2.0, 8.0), st.floats(0.5, 3.0),
                                    st.floats(2.0, 10.0)))
def test_node_follows_the_reference_with_a_compliance_through_pressure_steps(seed, k_m, sigma0, events,
                                                                            square):
    doc = _doc(k_m, sigma0)
    recs = _steps(doc["physical"], random_stream(doc["physical"], 12, seed), events, square)
    _follows(doc, recs)


def test_a_pressure_shock_that_drives_the_bounce_into_its_clamp():
    """A case a hypothesis search found: three alike compliances, and a transmitter's shock
    (15 % of its span, in the stream, within NAMUR) swings the tracker's bounce to its
    clamp (+-1 MPa here). The node reads each channel in kPa/16 steps, up to 600 Pa off the
    float reading (its gain within 3e-5, its 4 mA value in whole kPa); with float readings
    the reference's bounce parts from the node's by 450 Pa as the median passes to another
    pair of channels, the clamp takes both to the same value, and k p_l steps by 0.23 um
    on one side (0.053 % of rated). So the reference's observer reads the node's steps."""
    doc = _doc([5.09219104138202e-10] * 3 + [3.648055294435989e-10], 1e8)
    ph = doc["physical"]
    recs = _steps(ph, random_stream(ph, 12, 13), [], None)
    hits = []

    class Recording(reference.PressureTracker):
        def step(self, y):
            out = super().step(y)
            hits.append(self.tr is not None and self.on and abs(self.b0) >= self.lim_b)
            return out

    reference.compensate(ph, recs, tracker_class=Recording)
    assert any(hits)  # the bounce reached its clamp
    _follows(doc, recs)


def test_a_resonant_square_wave_drives_the_tracker_into_the_nodes_clamps():
    """The case hypothesis finds by chance, fixed: 10 MPa steps at the bounce frequency for 3 s
    on every channel; without the clamps in the reference the two part by ~15 % of rated."""
    doc = _doc([3e-10, 2.5e-10, 3.2e-10, 3e-10], 1e8)
    ph = doc["physical"]
    recs = _steps(ph, random_stream(ph, 20, 1), [], (2.8, 5.0, 3.0, 10.0))
    hits = []

    class Recording(reference.PressureTracker):
        def step(self, y):
            out = super().step(y)
            if self.tr is not None and self.on:
                hits.append(abs(self.b0) >= self.lim_b or abs(self.b1) >= self.lim_b)
            return out

    ref = reference.compensate(ph, recs, tracker_class=Recording)
    assert any(hits)  # the bounce reached the node's clamp
    ten, good, _ = run_node(Node(config.parse(doc)), recs)
    err = np.abs(ten - ref.tension_n)[good]
    assert err.max() <= 0.0005 * ph["rated_rope_tension_N"], err.max() / ph["rated_rope_tension_N"]


STROKE_DRAWS = int(os.environ.get("ROPEMON_STROKE_DRAWS", "96"))


def _stroke_draw(draw: int) -> tuple[dict, np.ndarray]:
    rng = random.Random(draw)
    k_m = [rng.uniform(1e-10, 6e-10) for _ in range(4)]
    alike = draw % 2 == 1
    if alike:
        k_m = [k_m[0]] + k_m[:3]
    stroke_sigmas = (1.0, 2.0, 3.0, 6.5)[draw % 4]
    stroke_settle_s = (0.0, 0.5, 4.0)[draw % 3]
    changes = {} if draw % 5 else {"pressure_step_max_Pa": 0.0}
    events = [(rng.uniform(0.1, 0.99), rng.randint(1, 2), rng.choice((-10.0, -5.0, 5.0, 10.0)))
              for _ in range(rng.randint(0, 3))]
    doc = _doc(k_m, rng.choice((1e7, 1e8)), stroke_sigmas=stroke_sigmas, stroke_settle_s=stroke_settle_s,
               **changes)
    ph = doc["physical"]
    recs = random_stream(ph, 8, rng.randrange(2**16))
    if alike:  # ropes 0 and 1: the same pressure and piston
        recs[:, 1] = recs[:, 0]
        recs[:, 5] = recs[:, 4]
    return doc, _steps(ph, recs, events, None)


@pytest.mark.parametrize("draw", range(STROKE_DRAWS))
def test_node_and_reference_take_the_same_strokes_with_aggressive_settings(draw):
    _follows(*_stroke_draw(draw))


def test_a_node_tracking_strokes_where_the_reference_does_not_is_disputed():
    """Stroke tracking runs only while every rope is healthy, started and warmed up: a node
    that tracks during the warm-up, or stops tracking (its state and cl zeroed) while the
    reference tracks, is disputed whatever its values."""
    doc, recs = _stroke_draw(0)
    tr = node_trace(doc, recs)
    on = np.flatnonzero(tr.tracking)
    assert 0 < on[0] and len(on) > 100
    f = tr.follow()
    f.tracking[on[0] - 1] = True  # still warming up
    reference.compensate(doc["physical"], recs, follow=f)
    assert f.disputes == [(on[0] - 1, "not tracking", "tracking")]
    f = tr.follow()
    dropped = on[50:60]
    f.tracking[dropped] = False
    f.state[dropped] = 0
    f.cl[dropped] = 0.0
    reference.compensate(doc["physical"], recs, follow=f)
    assert f.disputes == [(j, "tracking", "not tracking") for j in dropped.tolist()]


@pytest.mark.parametrize("slide_um_s", [8.0, 16.0, 30.0, 60.0, 66.0, 68.0, 76.0, 120.0])
def test_a_steady_slide_is_taken_over_without_leaning_and_grazes_the_threshold(slide_um_s):
    """A piston sliding steadily ahead of the others holds e about where the take-over
    (x_h taking over what e holds beyond a quarter of the threshold, 1/64 per sample)
    balances the slide: up to 66 um/s below the threshold (3 sigmas), from 68 um/s past it
    (a stroke). Rounded each sample, the take-over leaned the same way for seconds (0.47 %
    of rated at 18 um/s): its remainder is carried. At 76 um/s e meets the threshold within
    rounding and the reference alone ends a stroke at another sample; followed, they agree."""
    doc = _doc([3e-10] * 4, 1e8, stroke_sigmas=3.0)
    recs, _, _ = slide_stream(doc["physical"], 3e-10, 7, slide_um_s=slide_um_s)
    tr, _, follow = _follows(doc, recs)
    alone: list = []
    reference.compensate(doc["physical"], recs, strokes=alone)
    apart = _events(tr.state) != [(j, r) for j, r, _ in alone]
    assert apart == (slide_um_s == 76.0)
    assert len(follow.followed) >= 2 + apart  # two of cl's in the bounce, and a stroke's end


def test_a_slide_near_the_rest_holds_switch():
    """At 18 um/s a take-over rounded each sample without its remainder leans node and
    reference 0.47 % of rated apart. With it they are 0.06 % apart, the one case here
    beyond 0.05 %: rope 2's activity passes between the rest hold's threshold and twice it
    as the slide begins, where the hold's share of b's gain and the activity feed each
    other, and the two, 0.004 um apart in the activity (x_s in um/256), part for 80 ms."""
    doc = _doc([3e-10] * 4, 1e8, stroke_sigmas=3.0)
    recs, _, _ = slide_stream(doc["physical"], 3e-10, 7, slide_um_s=18.0)
    _follows(doc, recs, limit_pct=0.1)


def test_a_node_deciding_otherwise_than_its_values_is_disputed():
    """A stroke start put into the node's trace where the reference's rule on the node's
    values starts none is not followed: it is a dispute, and the reference keeps its own."""
    doc, recs = _stroke_draw(0)
    tr = node_trace(doc, recs)
    at = int(np.flatnonzero((tr.state[:, 0] == 0) & (tr.state[:, 1] != 0))[-20])  # tracking, no stroke
    follow = tr.follow()
    follow.state[at:at + 3] = (1, 1, 0)
    strokes: list = []
    reference.compensate(doc["physical"], recs, strokes=strokes, follow=follow)
    assert [j for j, _, _ in follow.disputes][:1] == [at]
    assert at not in [j for j, _, _ in strokes]
