"""The float reference alone: the model's physics (docs/model.md), independent of the node."""
from __future__ import annotations

import struct

import numpy as np

from ropemon import reference
from ropemon.nodeconfig import example_physical

C4, C20 = 9600, 48000


def _counts_p(pa):
    return np.round(C4 + np.asarray(pa) / 25e6 * (C20 - C4)).astype(np.uint16)


def _counts_x(m):
    return np.round(C4 + (np.asarray(m) + 0.05) / 0.1 * (C20 - C4)).astype(np.uint16)


def _records(p_pa, x_m):
    k = len(p_pa)
    r = np.zeros((k, 12), np.uint16)
    r[:, 0:4] = _counts_p(p_pa)[:, None]
    r[:, 4:8] = _counts_x(x_m)[:, None]
    r[:, 8], r[:, 9] = 60000, 0xFFFF
    return r


def test_pulled_then_held_reads_low_by_the_friction():
    """Rope pulls the piston out, then rests: the seal holds, p A reads below T by F > 0."""
    ph = example_physical()
    fs = ph["sample_hz"]
    t = np.arange(4 * fs) / fs
    x = np.clip(t, 0, 1) * 0.01                  # 10 mm out in 1 s, then rest
    p = np.full(len(t), 6e6)
    c = reference.compensate(ph, _records(p, x))
    end = -1
    assert abs(c.v_m_s[end, 0]) < 1e-9 and c.friction_n[end, 0] > 0.5 * 7400
    assert abs(c.tension_n[end, 0] - (c.raw_tension_n[end, 0] + c.friction_n[end, 0])) < 1e-6


def test_steady_sliding_friction_is_the_stribeck_curve():
    ph = example_physical()
    fs = ph["sample_hz"]
    v = 0.01
    t = np.arange(3 * fs) / fs
    c = reference.compensate(ph, _records(np.full(len(t), 10e6), -0.04 + v * t))
    fr = ph["friction"]
    lin = {k: fr[k]["intercept"] + fr[k]["slope"] * 10 for k in ("Fs", "Fc", "vs", "sigma2")}
    g = lin["Fc"] + (lin["Fs"] - lin["Fc"]) * np.exp(-(v / lin["vs"]) ** 2)
    assert abs(c.friction_n[-1, 0] - (g + lin["sigma2"] * v)) < 0.01 * g
    assert abs(c.v_m_s[-1, 0] - v) < 1e-4


def test_loss_has_the_sign_of_the_flow():
    ph = example_physical()
    fs = ph["sample_hz"]
    t = np.arange(2 * fs) / fs
    c = reference.compensate(ph, _records(np.full(len(t), 5e6), 0.02 * np.sin(2 * np.pi * t)))
    moving = np.abs(c.v_m_s[:, 0]) > 1e-3
    assert (np.sign(c.loss_n[moving, 0]) == np.sign(c.v_m_s[moving, 0])).all()


def test_failed_loop_gives_no_tension():
    ph = example_physical()
    r = _records(np.full(100, 5e6), np.zeros(100))
    r[50:60, 2] = 8000  # below 3.6 mA
    c = reference.compensate(ph, r)
    assert np.isnan(c.tension_n[50:60, 2]).all() and not np.isnan(c.tension_n[50:60, 1]).any()
    assert (c.fault_mask[50:60] == 0x04).all()


def test_read_rsens(tmp_path):
    r = _records(np.full(7, 5e6), np.zeros(7))
    p = tmp_path / "s.rsens"
    p.write_bytes(struct.pack("<4sHHHH", b"RSNS", 1, 4, 200, 0) + r.astype("<u2").tobytes() + b"x")
    ropes, hz, recs = reference.read_rsens(p)
    assert (ropes, hz) == (4, 200) and (recs == r).all()
