"""The band of each rope's tension (ropemon.station.uncertainty): physical range, anchor, flips,
relaxation, faults, gaps, and the deviation's exact extremes."""
from __future__ import annotations

import itertools
import math
import random

import pytest

from ropemon.station.protocol import Frame, L, Rope
from ropemon.station.uncertainty import BandParams, SealBandTracker, deviation_bounds

AREA = 0.01   # m^2: 1 kPa -> 10 N
PHYS = {"ropes": 4, "cylinder_area_m2": [AREA] * 4,
        "friction": {"Fs": {"intercept": 0.0, "slope": 1000.0}, "Fc": {"intercept": 0.0, "slope": 800.0},
                     "residual": 100.0}}
P = BandParams.from_physical({**PHYS, "band_anchor": True, "band_margin": 0.10})


def frame(ropes, seq, fault_mask=0, dt_ms=100):
    """ropes: per rope (tension N, pressure kPa), or None for a rope with no healthy sample."""
    recs = []
    for r in ropes:
        if r is None:
            recs.append(Rope(L.TENSION_ABSENT, L.TENSION_ABSENT, L.TENSION_ABSENT, L.RAW_KPA_ABSENT))
        else:
            t = round(r[0] / 10)
            recs.append(Rope(t, t, t, round(r[1])))
    return Frame(1, 0, 1, fault_mask, seq, seq * dt_ms, 0, tuple(recs), 0, 0, 7400, L.OIL_TEMP_ABSENT)


def tf(f_n, kpa):
    """(tension, pressure) of a rope whose friction estimate is f_n at kpa."""
    return (kpa * 1000 * AREA + f_n, kpa)


class Feed:
    def __init__(self, params=P):
        self.tr = SealBandTracker(params)
        self.seq = 0

    def __call__(self, ropes, **kw):
        u = self.tr.update(frame(ropes, self.seq, **kw))
        self.seq += 1
        return u


def anchored(f_n=4000.0, n=4):
    """Pressure 4000 -> 5000 kPa (10 kN of p A, beyond S) with the estimate saturated at +f_n."""
    feed = Feed()
    for k in range(11):
        feed([tf(f_n, 4000 + 100 * k)] * n)
    return feed


def test_params_defaults_validation_and_residual():
    assert P.margin == 0.10 and P.gain == 1.0 and P.saturation == 0.7 and P.blind_s == 2.0
    assert P.anchor_travel == 0.25 and P.anchor is True
    d = BandParams.from_physical(PHYS)
    assert d.anchor is False and d.margin == 0.25
    with pytest.raises(ValueError, match="physical.band_anchor"):
        BandParams.from_physical({**PHYS, "band_anchor": 1})
    assert P.residual_n == 100.0
    s, fc, floor = P.limits(5000)
    assert (s, fc, floor) == pytest.approx((1.1 * 5000 + 200, 4000, 200))
    no_res = BandParams.from_physical({**PHYS, "friction": {k: v for k, v in PHYS["friction"].items()
                                                              if k != "residual"}})
    assert no_res.limits(5000)[2] == pytest.approx(2 * 0.05 * 4000)   # 5 % of Fc(p)
    fitted = BandParams.from_physical({**PHYS, "friction": no_res_friction(),
                                       "friction_residual_frac": {"sliding": 0.02, "presliding": 0.08}})
    assert fitted.limits(5000)[2] == pytest.approx(2 * 0.08 * 5000)   # the larger part, of Fs(p)
    assert BandParams.from_physical({"ropes": 4, "cylinder_area_m2": [AREA] * 4}) is None
    with pytest.raises(ValueError, match="physical.band_gain"):
        BandParams.from_physical({**PHYS, "band_gain": -1})
    assert BandParams.from_physical({**PHYS, "band_margin": 0.3}).margin == 0.3


def no_res_friction():
    return {k: v for k, v in PHYS["friction"].items() if k != "residual"}


def test_no_anchor_at_start_is_the_whole_physical_range():
    feed = Feed()
    u = feed([tf(0.0, 5000)] * 4)
    s = P.limits(5000)[0]
    assert u == pytest.approx([s] * 4)
    assert not any(r.vouched for r in feed.tr.last)


def test_saturated_and_driven_estimate_is_anchored_to_the_floor():
    feed = anchored()
    u = feed([tf(4000.0, 5000)] * 4)
    assert u == pytest.approx([200.0] * 4)
    assert all(r.vouched for r in feed.tr.last)


def test_saturated_at_rest_is_not_anchored():
    """Saturated but the pressure never moved it there: not trusted."""
    feed = Feed()
    for _ in range(50):
        u = feed([tf(4000.0, 5000)] * 4)
    s = P.limits(5000)[0]
    assert u == pytest.approx([s + 4000.0] * 4)          # the whole [pA - S, pA + S] about T^ = pA + 4 kN
    assert not any(r.vouched for r in feed.tr.last)


def test_a_flip_keeps_a_band_covering_the_held_value():
    """Unloading by 3 kN of p A (less than S): every estimate flips to -4 kN; the seal may still hold
    +4 kN, so the band covers it, through a long rest after."""
    feed = anchored()
    for k in range(1, 4):
        feed([tf(4000.0 - 2700 * k, 5000 - 100 * k)] * 4)
    for _ in range(100):
        feed([tf(-3800.0, 4700)] * 4)
    for r in feed.tr.last:
        assert r.hi >= r.pa + 4000.0 - 1e-6 and r.lo <= r.t_hat <= r.hi
        assert r.hi <= r.pa + r.s + 1e-6
    # a sustained drop in the sliding direction (beyond S) moves the anchor: the band shrinks
    for k in range(1, 11):
        feed([tf(-3800.0, 4700 - 100 * k)] * 4)
    assert feed([tf(-3800.0, 3700)] * 4) == pytest.approx([200.0] * 4)


def test_a_relaxed_estimate_covers_both_sides():
    """A seal holding -4 kN read as 0: the relaxation from the anchor is the band, both ways."""
    feed = anchored()
    u = feed([tf(0.0, 5000)] * 4)
    assert u == pytest.approx([4000.0] * 4)
    r = feed.tr.last[0]
    assert r.lo == pytest.approx(r.pa - 4000.0) and r.hi == pytest.approx(r.pa + 4000.0)


def test_the_interval_never_leaves_the_physical_range():
    rng = random.Random(7)
    feed = anchored()
    kpa = 5000.0
    for _ in range(2000):
        kpa = min(20000.0, max(100.0, kpa + rng.gauss(0, 80)))
        ropes = []
        for _ in range(4):
            s = P.limits(round(kpa))[0]
            ropes.append(tf(rng.uniform(-1.3, 1.3) * s, kpa))
        feed(ropes, fault_mask=rng.choice([0] * 20 + [1, 0x20]))
        for r in feed.tr.last:
            assert max(0.0, r.pa - r.s) - 1e-6 <= r.lo <= r.hi <= r.pa + r.s + 1e-6
            assert r.hi - r.lo >= min(2 * 200.0, r.s) - 1e-6       # never narrower than the floor


def test_a_faulted_rope_is_not_vouched_for_and_loses_its_anchor():
    feed = anchored()
    feed([tf(4000.0, 5000)] * 4, fault_mask=0x20)      # rope 1's displacement loop
    assert not feed.tr.last[1].vouched and feed.tr.last[0].vouched
    s = P.limits(5000)[0]
    assert feed([tf(4000.0, 5000)] * 4)[1] == pytest.approx(s + 4000.0)   # [pA - S, pA + S] about T^


def test_an_absent_rope_gets_the_physical_range_at_the_manifold_pressure():
    feed = anchored()
    feed([tf(4000.0, 5000), None, tf(4000.0, 5000), tf(4000.0, 5200)])
    r = feed.tr.last[1]
    assert not r.present and r.pa == pytest.approx(5000 * 1000 * AREA)   # median of 5000, 5000, 5200
    s = P.limits(5000)[0]
    assert (r.lo, r.hi) == pytest.approx((r.pa - s, r.pa + s))


def test_the_band_grows_when_frames_stop_and_a_long_gap_drops_the_anchor():
    feed = anchored()
    feed([tf(4000.0, 5000)] * 4)
    widths = [feed.tr.intervals(age)[0] for age in (0.0, 0.5, 1.0, 2.0, 10.0)]
    spans = [r.hi - r.lo for r in widths]
    assert spans == sorted(spans) and spans[0] < spans[1] < spans[3]
    s = P.limits(5000)[0]
    assert spans[3] == pytest.approx(2 * s) and spans[4] == pytest.approx(2 * s)
    assert not widths[3].vouched
    # frames back after a gap longer than band_blind_s: nothing is vouched for until re-anchored
    feed.seq += 30
    assert feed([tf(4000.0, 5000)] * 4) == pytest.approx([s + 4000.0] * 4)


def test_a_node_reset_drops_the_anchor():
    feed = anchored()
    feed.seq = 1 << 20                                   # boot 1
    feed.tr._last_ms = feed.seq * 100 - 100             # no gap: only the boot counter moved
    assert not any(r.vouched for r in (feed([tf(4000.0, 5000)] * 4), feed.tr.last)[1])


def test_deviation_extremes_are_exact_over_the_intervals():
    rng = random.Random(3)
    for _ in range(50):
        feed = Feed()
        feed([tf(rng.uniform(-3000, 3000), rng.uniform(4000, 6000)) for _ in range(4)])
        iv = feed.tr.last
        bounds = deviation_bounds(iv)
        for i, b in enumerate(bounds):
            corners = []
            for pick in itertools.product(*[(max(0.0, r.lo), r.hi) for r in iv]):
                corners.append(4 * pick[i] / sum(pick) - 1)
            assert b.d_max == pytest.approx(max(max(corners), b.dev))
            assert b.d_min == pytest.approx(min(min(corners), b.dev))
            for _ in range(20):   # no point inside the box beyond the corners
                t = [rng.uniform(max(0.0, r.lo), r.hi) for r in iv]
                d = 4 * t[i] / sum(t) - 1
                assert b.d_min - 1e-12 <= d <= b.d_max + 1e-12
            assert b.band == pytest.approx(b.reach - abs(b.dev))


def test_first_order_bound_holds_for_small_bands():
    """|d_i| <= |d^_i| + (u_i + (1 + d^_i) mean u) / mean(T^) to first order (module doc)."""
    feed = anchored()
    feed([tf(4000.0, 5000), tf(4000.0, 5000), tf(4000.0, 5000), tf(3500.0, 5300)])
    iv = feed.tr.last
    b = deviation_bounds(iv)[3]
    u = [r.u for r in iv]
    mean_t = sum(r.t_hat for r in iv) / 4
    bound = abs(b.dev) + (u[3] + (1 + b.dev) * sum(u) / 4) / mean_t
    assert b.reach <= bound * 1.01 and b.band > 0
    assert math.isfinite(b.reach)


def test_by_default_no_rope_is_anchored_and_the_band_is_the_seals_physical_range():
    """The node's saturated estimate is not taken as the seal's force (anchoring is opt-in): the
    band stays [p A - S, p A + S] however long the pressure drives the seals."""
    tr = SealBandTracker(BandParams.from_physical(PHYS))
    for k in range(50):
        tr.update(frame([tf(4000.0, 4000 + 100 * k)] * 4, k))
    for r in tr.last:
        s = 1.25 * r.pa / AREA / 1000 / 1000 * 1000 + 200   # (1 + 0.25) Fs(p) + 2 r, Fs = 1000 N/MPa
        assert not r.vouched
        assert r.lo == pytest.approx(r.pa - s, abs=1e-6) and r.hi == pytest.approx(r.pa + s, abs=1e-6)


def test_hidden_reach_is_the_whole_bands_reach_with_the_ropes_equal():
    """The imbalance the seals can hide: every rope at T, its true tension anywhere in [T - S, T + S];
    rope i at its top and the others at their bottom gives n (T + S) / (n T + S - (n - 1) S) - 1."""
    from ropemon.station.uncertainty import hidden_reach

    band = BandParams.from_physical(PHYS)          # margin 0.25, residual 100 N: S = 1.25 Fs(p) + 200 N
    t = 50_000.0                                   # N: 5000 kPa on 0.01 m^2
    s = 1.25 * 1000.0 * 5.0 + 200.0
    n = 4
    expect = max(n * (t + s) / ((t + s) + (n - 1) * (t - s)) - 1, 1 - n * (t - s) / ((t - s) + (n - 1) * (t + s)))
    assert hidden_reach(band, t) == pytest.approx(expect)
    assert hidden_reach(band, 0.0) == 0.0
    with pytest.raises(ValueError, match="rope_n"):
        hidden_reach(band, math.nan)


def test_hidden_reach_is_what_commissioning_prints():
    from ropemon.commission.config_cli import deviation_cover
    from ropemon.station.uncertainty import hidden_reach

    cover = deviation_cover({**PHYS, "imbalance_frac": 0.1}, 20_000.0, 60_000.0)
    band = BandParams.from_physical(PHYS)
    assert hidden_reach(band, 20_000.0) == pytest.approx(cover["empty_reach"])
    assert hidden_reach(band, 60_000.0) == pytest.approx(cover["rated_reach"])
