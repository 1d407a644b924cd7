"""The node's imbalance and battery-low status bits at exactly their limits and one count either
side, on the node's own code (the viper kernel where the port has a native emitter, and the
plain one), with the shipped config:

- imbalance (ST_IMBALANCE): a rope's window mean deviates from the ropes' mean by more than
  `imbalance_permille` of it; exactly at the limit is not beyond it;
- battery low (ST_BATTERY_LOW): the window's battery voltage below `battery_low_mv`; exactly
  at it is not low.

Runs under CPython (pytest) and the real MicroPython (tests/run_micropython.py).
"""
import array
import struct

from firmware_rig import frame_raw, node_doc

from ropenode import kernel, layout
from ropenode.config import parse
from ropenode.node import K, Node

N = 4
MID = 30000        # mid-scale pressure and displacement counts
BATT_OK = 60000    # 12 V
_CFG = []


def _cfg():
    if not _CFG:
        _CFG.append(parse(node_doc()))
    return _CFG[0]


def _steps():
    """The kernel the Node picks on this port, and the plain one if that is another."""
    out = [K.step]
    if K.step is not kernel.step:
        out.append(kernel.step)
    return out


def _window(p_counts, batt=BATT_OK, step=None):
    """One frame window of a fresh node on steady input: (rope means in daN, status, battery mV)."""
    node = Node(_cfg(), step=step)
    rec = array.array("H", list(p_counts) + [MID] * N + [batt, 0xFFFF, 0, 0])
    buf = bytearray(layout.MAX_WIRE_LEN)
    for _ in range(1000):
        if node.sample(rec):
            raw = frame_raw(buf, node.frame_into(buf))
            h = struct.unpack_from(layout.HEADER_FMT, raw, 0)
            assert h[1] == layout.KIND_DATA and h[3] == 0, h
            means = [struct.unpack_from(layout.ROPE_FMT, raw, layout.HEADER_LEN + i * layout.ROPE_LEN)[0]
                     for i in range(N)]
            tail = struct.unpack_from(layout.TAIL_FMT, raw, layout.HEADER_LEN + N * layout.ROPE_LEN)
            return means, h[6], tail[2]
    raise AssertionError("no frame")


def _imbalanced(status):
    return bool(status & layout.ST_IMBALANCE)


def _low(status):
    return bool(status & layout.ST_BATTERY_LOW)


def test_imbalance_bit_exactly_at_the_limit_and_one_count_either_side():
    lim = _cfg().imbalance_permille
    assert 0 < lim < 1000
    # rope 0 above the others' mean: 1000 * ((N - 1) * a - B) == lim * (a + B) at the limit,
    # a = rope 0's mean, B the other three's sum (all daN): a = B (1000 + lim) / ((N - 1) 1000 - lim).
    # Rope 1's pressure is moved until B gives a whole a; the others stay at mid-scale.
    den = (N - 1) * 1000 - lim
    c1 = MID
    while True:
        means, status, _ = _window([MID, c1, MID, MID])
        b = means[1] + means[2] + means[3]
        if b * (1000 + lim) % den == 0:
            break
        c1 += 1
        assert c1 < MID + 400, "no rope-1 pressure gives a whole limit"
    assert not _imbalanced(status)
    a = b * (1000 + lim) // den
    # rope 0's mean against its counts is about linear: aim at a, then walk count by count
    m_lo = means[0]
    m_hi = _window([MID + 1000, c1, MID, MID])[0][0]
    c0 = MID + (a - 1 - m_lo) * 1000 // (m_hi - m_lo) - 3
    seen = {}
    for _ in range(40):
        means, status, _ = _window([c0, c1, MID, MID])
        m = means[0]
        if m > a + 1:
            break
        if m >= a - 1 and m not in seen:
            seen[m] = c0
        c0 += 1
    assert sorted(seen) == [a - 1, a, a + 1], (a, seen)
    for step in _steps():
        for m, want in ((a - 1, False), (a, False), (a + 1, True)):
            means, status, _ = _window([seen[m], c1, MID, MID], step=step)
            tot = sum(means)
            assert means[0] == m and tot == m + b, (means, m, b)
            dev = (N * m - tot) * 1000      # rope 0's deviation from the mean, times N * 1000
            assert (dev > lim * tot) == want and (dev == lim * tot) == (m == a), (m, dev, lim * tot)
            assert _imbalanced(status) == want, (step, m, a, status)


def test_imbalance_limit_holds_below_the_mean_too():
    """Rope 0 low: 1000 * (B - (N - 1) a) == lim (a + B); a whole a is searched for likewise."""
    lim = _cfg().imbalance_permille
    den = (N - 1) * 1000 + lim
    c1 = MID
    while True:
        means, _, _ = _window([MID, c1, MID, MID])
        b = means[1] + means[2] + means[3]
        if b * (1000 - lim) % den == 0:
            break
        c1 += 1
        assert c1 < MID + 400, "no rope-1 pressure gives a whole limit"
    a = b * (1000 - lim) // den
    m_mid = means[0]
    m_lo = _window([MID - 1000, c1, MID, MID])[0][0]
    c0 = MID - (m_mid - (a + 1)) * 1000 // (m_mid - m_lo) + 3
    seen = {}
    for _ in range(40):
        means, _, _ = _window([c0, c1, MID, MID])
        m = means[0]
        if m < a - 1:
            break
        if m <= a + 1 and m not in seen:
            seen[m] = c0
        c0 -= 1
    assert sorted(seen) == [a - 1, a, a + 1], (a, seen)
    for step in _steps():
        for m, want in ((a + 1, False), (a, False), (a - 1, True)):
            means, status, _ = _window([seen[m], c1, MID, MID], step=step)
            assert means[0] == m and sum(means) == m + b, (means, m, b)
            assert _imbalanced(status) == want, (step, m, a, status)


def test_battery_low_bit_exactly_at_the_limit_and_one_count_either_side():
    cfg = _cfg()
    low = cfg.battery_low_mv
    mul, sh = cfg.battery_mv_mul, cfg.battery_mv_shift

    def mv(c):   # the node's conversion of the window's mean counts, rounded
        return (c * mul + ((1 << sh) >> 1)) >> sh
    c = ((low << sh) - ((1 << sh) >> 1)) // mul   # about the lowest count that reads the limit itself
    while mv(c) >= low:
        c -= 1
    while mv(c) < low:
        c += 1
    for step in _steps():
        for counts, want_mv, want_low in ((c - 1, low - 1, True), (c, low, False), (c + 1, None, False)):
            _, status, batt = _window([MID] * N, batt=counts, step=step)
            if want_mv is not None:
                assert batt == want_mv, (counts, batt, want_mv)
            else:
                assert batt >= low, (counts, batt)
            assert _low(status) == want_low, (step, counts, batt, low, status)
        # and a millivolt either side, by the reported voltage
        for counts in (c - 6, c + 5):
            _, status, batt = _window([MID] * N, batt=counts, step=step)
            assert _low(status) == (batt < low), (counts, batt, low)
