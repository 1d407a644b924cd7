"""Synthetic sensor streams (numpy) for the CPython differential tests of the node.

Not a test module: helpers imported by test_*_cpython.py. Words follow
docs/data-formats.md; the generator covers the full sensor ranges, rest,
reversals, slow creep, shocks and NAMUR faults.
"""
from __future__ import annotations

import array

import numpy as np

from ropemon.firmware import node_module

K = node_module("kernel")  # state offsets (the CPython Node runs the plain kernel)


def random_stream(ph: dict, seconds: float, seed: int, faults: bool = False) -> np.ndarray:
    """records[k, 2N+4] uint16: per rope a pressure and a displacement random walk."""
    rng = np.random.default_rng(seed)
    n, fs = ph["ropes"], ph["sample_hz"]
    k = int(seconds * fs)
    w = 2 * n + 4
    rec = np.zeros((k, w), np.uint16)
    seg = max(k // 6, 1)
    for i in range(n):
        pc = ph["pressure_channels"][i]
        c4, c20 = pc["counts_4mA"], pc["counts_20mA"]
        dc = ph["displacement_channels"][i]
        clo, chi = dc["counts_lo"], dc["counts_hi"]
        # pressure: random walk with occasional shocks, reflected inside 4..20 mA
        steps = rng.normal(0, (c20 - c4) * 0.002, k)
        shocks = rng.random(k) < 0.004
        steps[shocks] += rng.normal(0, (c20 - c4) * 0.15, shocks.sum())
        p = _reflect(c4 + (c20 - c4) * rng.random() + np.cumsum(steps), c4, c20)
        # displacement: segments of rest, slow creep, oscillation (reversals), random walk, jumps
        t = np.arange(k) / fs
        span = chi - clo
        mid = clo + span * (0.3 + 0.4 * rng.random())
        x = np.full(k, mid)
        kinds = rng.permutation(6)
        for s in range(6):
            a, b = s * seg, (s + 1) * seg if s < 5 else k
            kind = kinds[s]
            tt = t[a:b] - t[a]
            if kind == 0:      # rest
                x[a:b] = x[a - 1] if a else mid
            elif kind == 1:    # steady sliding through the Stribeck region, 0.2..10 mm/s
                v_counts = span / 0.1 * 1e-3 * np.exp(rng.uniform(np.log(0.2), np.log(10)))
                x[a:b] = (x[a - 1] if a else mid) + tt * v_counts * rng.choice([-1, 1])
            elif kind == 2:    # oscillation with reversals, up to ~5 cm/s
                amp = span * rng.uniform(0.001, 0.05)
                x[a:b] = (x[a - 1] if a else mid) + amp * np.sin(2 * np.pi * rng.uniform(0.2, 3) * tt)
            elif kind == 3:    # random walk
                x[a:b] = (x[a - 1] if a else mid) + np.cumsum(rng.normal(0, span * 3e-4, b - a))
            elif kind == 4:    # shock steps
                x[a:b] = (x[a - 1] if a else mid) + span * 0.1 * (((tt * 2).astype(int) % 2) - 0.5)
            else:              # fast ramp to the end stop and back (saturates v_max)
                x[a:b] = (x[a - 1] if a else mid) + span * 0.3 * np.sin(np.pi * tt / max(tt[-1], 1e-9))
        x = _reflect(x, clo, chi)
        rec[:, i] = np.round(p).astype(np.uint16)
        rec[:, n + i] = np.round(x).astype(np.uint16)
        if faults:
            span_p = c20 - c4
            bad = rng.random(k) < 0.01
            rec[bad, i] = rng.choice([0, c4 - span_p // 30, c20 + span_p // 14, 65535], bad.sum())
            badx = rng.random(k) < 0.005
            rec[badx, n + i] = rng.choice([0, 65535], badx.sum())
    rec[:, 2 * n] = 60000
    rec[:, 2 * n + 1] = 0xFFFF
    rec[:, 2 * n + 2] = (np.cumsum(rng.integers(-3, 4, k)) & 0xFFFF).astype(np.uint16)
    rec[:, 2 * n + 3] = 0
    return rec


def _reflect(v: np.ndarray, lo: float, hi: float) -> np.ndarray:
    span = hi - lo
    u = np.mod(v - lo, 2 * span)
    return lo + np.where(u > span, 2 * span - u, u)


def run_node(node, recs: np.ndarray, per_sample: bool = True):
    """Feed records through a ropenode Node; return (tension[k, n], good[k, n], frames bytes list)."""
    n = node.n
    k = recs.shape[0]
    rec = array.array("H", bytes(2 * recs.shape[1]))
    ten = np.zeros((k, n))
    good = np.zeros((k, n), bool)
    buf = bytearray(node_module("layout").MAX_WIRE_LEN)
    frames = []
    rows = recs.tolist()
    for j in range(k):
        rec[:] = array.array("H", rows[j])
        ready = node.sample(rec)
        if per_sample:
            ten[j] = node.rope(K.TENSION_N)
            g = node.S[K.GOOD]
            good[j] = [(g >> i) & 1 for i in range(n)]
        if ready:
            m = node.frame_into(buf)
            frames.append(bytes(buf[:m]))
    return ten, good, frames


def slide_stream(ph: dict, k_m: float, seed: int, slide_um_s: float = 20.0, seconds: float = 34.0):
    """(records, true positions[k, N], pressure) of differential sliding outside a stroke: the
    pressure rises by 1 MPa at 50 kPa/s from 6 s (every piston moves k dp, 15 um/s at
    3e-10 m/Pa), and from 6 s to 26 s rope 1's piston slides `slide_um_s` ahead of that
    while rope 2's slides as far back (the oil they share is kept), so the two part by
    ~1 mm at 25 um/s; then a 2 Hz bounce that all share. 2 counts of displacement noise,
    no oil temperature input."""
    n = int(ph["ropes"])
    fs = int(ph["sample_hz"])
    t = np.arange(0, seconds, 1 / fs)
    p_pa = 5e6 + 50e3 * np.clip(t - 6, 0, 20)
    after = np.clip(t - 26, 0, None)
    p_pa = p_pa + np.where(t >= 26, 2e4 * np.sin(2 * np.pi * 2 * after) * np.exp(-after / 2), 0)
    x = k_m * (p_pa - p_pa[0])[:, None] * np.ones(n)
    slide = slide_um_s * 1e-6 * np.clip(t - 6, 0, 20)
    x[:, 0] += slide
    x[:, 1] -= slide
    return wind_records(ph, p_pa, x, seed), x, p_pa


def wind_records(ph: dict, p_pa: np.ndarray, x: np.ndarray, seed: int) -> np.ndarray:
    """Sensor records of one pressure for every rope and each rope's piston position x (m, about
    mid-channel), with 2 counts of displacement noise; speed counter still, no battery reading."""
    n = int(ph["ropes"])
    recs = np.zeros((len(p_pa), 2 * n + 4), np.uint16)
    rng = np.random.default_rng(seed)
    for i in range(n):
        pc, dc = ph["pressure_channels"][i], ph["displacement_channels"][i]
        lo, hi = pc["range_Pa"]
        recs[:, i] = np.round(pc["counts_4mA"] + (p_pa - lo) / (hi - lo) * (pc["counts_20mA"] - pc["counts_4mA"]))
        ylo, yhi = dc["range_m"]
        cx = dc["counts_lo"] + (0.5 * (ylo + yhi) + x[:, i] - ylo) / (yhi - ylo) * (dc["counts_hi"] - dc["counts_lo"])
        recs[:, n + i] = np.round(cx + rng.normal(0, 2.0, len(p_pa)))
    recs[:, 2 * n + 1] = 0xFFFF
    return recs
