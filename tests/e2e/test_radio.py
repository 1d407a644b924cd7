"""Radio model: coverage, loss and bit errors growing with distance and depth, duplicates."""
import numpy as np
import pytest

from ropemon.lab.radio import (RadioParams, Receiver, bit_error_rate, flip_bits, loss_probability,
                           paper_receivers, transmit)

SHAFT = 810.0
WIRE = bytes(range(1, 60)) + b"\x00"


def frames_at(depth_m, n):
    return [(0.1 * i, depth_m, WIRE) for i in range(n)]


def test_receivers_cover_the_shaft_with_overlap():
    pit, mid = paper_receivers(SHAFT)
    for depth in np.linspace(0, SHAFT, 200):
        assert pit.distance_m(depth) is not None or mid.distance_m(depth) is not None
    overlap = [d for d in np.linspace(0, SHAFT, 200)
               if pit.distance_m(d) is not None and mid.distance_m(d) is not None]
    assert overlap and min(overlap) > 0.3 * SHAFT and max(overlap) < 0.7 * SHAFT
    assert pit.distance_m(0.9 * SHAFT) is None      # the pithead cannot hear the shaft bottom
    assert mid.distance_m(10.0) is None


def test_loss_and_bit_errors_grow_with_depth():
    p = RadioParams(shaft_m=SHAFT)
    pit, mid = paper_receivers(SHAFT)
    losses = [loss_probability(p, pit, d) for d in (0, 100, 250, 450)]
    assert losses == sorted(losses) and losses[0] < losses[-1]
    bers = [bit_error_rate(p, pit, d) for d in (0, 100, 250, 450)]
    assert bers == sorted(bers) and bers[0] < bers[-1]
    # Below weak_below_m the link degrades even near the mid-shaft receiver.
    calm = RadioParams(shaft_m=SHAFT, weak_loss_add=0.0, weak_ber_factor=1.0)
    assert loss_probability(p, mid, 700) > loss_probability(calm, mid, 700)
    assert bit_error_rate(p, mid, 700) > bit_error_rate(calm, mid, 700)
    assert loss_probability(p, pit, 300) == loss_probability(calm, pit, 300)


def test_measured_loss_follows_the_model():
    p = RadioParams(shaft_m=SHAFT)
    near = transmit(frames_at(20.0, 2000), paper_receivers(SHAFT), p, seed=1)
    far = transmit(frames_at(790.0, 2000), paper_receivers(SHAFT), p, seed=1)
    assert near.lost < far.lost
    assert near.lost / 2000 < 0.05
    pit_only = [h for h in near.heard_by if h]
    assert all(h == ("pithead",) for h in pit_only)
    errs_near = sum(d.bit_errors for d in near.deliveries["pithead"])
    errs_far = sum(d.bit_errors for d in far.deliveries["mid-shaft"])
    assert errs_near < errs_far


def test_overlap_delivers_duplicates_and_retries_duplicate_too():
    p = RadioParams(shaft_m=SHAFT, loss_near=0, loss_edge=0, weak_loss_add=0, ber_near=0,
                    ber_edge=0, retry_dup=0.5)
    r = transmit(frames_at(0.5 * SHAFT, 200), paper_receivers(SHAFT), p, seed=3)
    assert all(set(h) == {"pithead", "mid-shaft"} for h in r.heard_by)
    n = sum(len(v) for v in r.deliveries.values())
    assert 400 < n < 800                      # both receivers, about half the frames twice
    for v in r.deliveries.values():
        assert all(d.data == WIRE for d in v)
        ts = [d.t_s for d in v]
        assert ts == sorted(ts)


def test_same_seed_same_result_other_seed_differs():
    p = RadioParams(shaft_m=SHAFT)
    fr = frames_at(600.0, 300)
    a = transmit(fr, paper_receivers(SHAFT), p, seed=7)
    b = transmit(fr, paper_receivers(SHAFT), p, seed=7)
    c = transmit(fr, paper_receivers(SHAFT), p, seed=8)
    data = lambda r: [(d.frame_index, d.data) for v in r.deliveries.values() for d in v]
    assert data(a) == data(b)
    assert data(a) != data(c)


def test_flip_bits_flips_exactly_what_it_reports():
    rng = np.random.default_rng(0)
    for _ in range(50):
        out, n = flip_bits(WIRE, 0.01, rng)
        diff = sum(bin(x ^ y).count("1") for x, y in zip(out, WIRE))
        assert diff == n and len(out) == len(WIRE)


def test_bad_params_refused_naming_the_field():
    with pytest.raises(ValueError, match="loss_edge"):
        transmit([], [Receiver("x", 0, 0, 1)], RadioParams(loss_edge=1.5))
    with pytest.raises(ValueError, match="ber_near"):
        RadioParams(ber_near=-1).validate()
