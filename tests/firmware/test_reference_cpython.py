"""The float reference alone: the model's physics (docs/model.md), independent of the node."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from ropemon.commission import reference
from ropemon.commission.nodejson import example_physical

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
    """Rope pulls the piston out, then rests: the seal holds, p A reads below T by F > 0. The
    stream has no shaft pulses (the hoist at rest throughout): the tension carries of F what
    the seal state from the piston's own travel holds, which slid out at Fc (do no harm)."""
    ph = example_physical()
    fs = ph["sample_hz"]
    t = np.arange(4 * fs) / fs
    x = np.clip(t, 0, 1) * 0.01                  # 10 mm out in 1 s, then rest
    p = np.full(len(t), 6e6)
    c = reference.compensate(ph, _records(p, x))
    end = -1
    assert abs(c.v_m_s[end, 0]) < 1e-9 and c.friction_n[end, 0] > 0.5 * 7400
    shown = c.friction_n[end, 0] - c.held_n[end, 0]
    assert abs(c.tension_n[end, 0] - (c.raw_tension_n[end, 0] + shown)) < 1e-6
    assert 0.5 * 7400 < shown <= c.friction_n[end, 0]


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


def _lugre_truth(ph, x, p_pa):
    """The seal's friction along the true (noiseless) position x: exact LuGre, 8 sub-steps."""
    from ropemon.lab.testbed import LuGre

    fs = ph["sample_hz"]
    law = LuGre(ph["friction"])
    v = np.gradient(x) * fs
    out = np.empty(len(x))
    for j, vj in enumerate(v):
        for _ in range(8):
            law.force(vj, p_pa / 1e6, 1 / fs / 8)
        out[j] = law.force(vj, p_pa / 1e6, 0.0)
    return out


def _noisy(x, seed, noise_m=2e-5):
    return x + np.random.default_rng(seed).normal(0.0, noise_m, len(x))


def test_friction_holding_at_rest_survives_displacement_noise():
    """Pulled 2 mm, then 12 s at rest with 20 um rms noise (the default channel's): the
    held friction stays (the plain implicit-Euler LuGre forgot it within ~1 s)."""
    ph = example_physical()
    fs = ph["sample_hz"]
    t = np.arange(14 * fs) / fs
    x = np.clip(t, 0, 2) * 1e-3
    truth = _lugre_truth(ph, x, 6e6)
    c = reference.compensate(ph, _records(np.full(len(t), 6e6), _noisy(x, 1)))
    rest = slice(-2 * fs, None)
    held = truth[rest].mean()
    assert held > 6000  # the seal really holds ~6.7 kN
    assert abs(c.friction_n[rest, 0].mean() - held) < 0.05 * held
    assert np.sqrt(np.mean((c.friction_n[fs:, 0] - truth[fs:]) ** 2)) < 0.05 * held


@pytest.mark.parametrize("seed", [2, 3])
def test_slow_creep_and_presliding_reversals_under_noise(seed):
    """After a 1 mm pull (a known seal state: the boot state is not), creep at 10 um/s
    (a twentieth of the velocity noise) or +-60 um reversals in pre-sliding: the
    estimate follows the true LuGre within 5 % of Fs."""
    ph = example_physical()
    fs = ph["sample_hz"]
    t = np.arange(16 * fs) / fs
    pull = np.clip(t, 0, 1) * 1e-3
    after = np.clip(t - 2, 0, None)
    fs_n = ph["friction"]["Fs"]["intercept"] + 6 * ph["friction"]["Fs"]["slope"]
    for x in (pull - after * 1e-5, pull + 6e-5 * np.sin(2 * np.pi * after / 7)):
        truth = _lugre_truth(ph, x, 6e6)
        c = reference.compensate(ph, _records(np.full(len(t), 6e6), _noisy(x, seed)))
        err = c.friction_n[3 * fs:, 0] - truth[3 * fs:]
        assert np.sqrt(np.mean(err ** 2)) < 0.05 * fs_n


def test_lugre_state_is_bounded_by_g_whatever_the_input():
    """|sigma0 z| <= g: full-speed jumps of the displacement count, both ways."""
    ph = example_physical()
    rng = np.random.default_rng(4)
    x = np.cumsum(rng.choice([-1, 1], 2000)) * 2e-3
    c = reference.compensate(ph, _records(np.full(2000, 20e6), np.clip(x, -0.049, 0.049)))
    fr = ph["friction"]
    fs_n = fr["Fs"]["intercept"] + 20 * fr["Fs"]["slope"]
    s2 = fr["sigma2"]["intercept"] + 20 * fr["sigma2"]["slope"]
    damp = fr["sigma1"] * ph["sample_hz"] / fr["sigma0"] * 2 * fs_n
    assert (np.abs(c.friction_n[:, 0] - s2 * c.v_m_s[:, 0]) <= fs_n + damp + 1e-6).all()
