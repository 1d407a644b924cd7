"""The pressure tracker (docs/model.md, "Pressure tracker"): the steady-state Kalman filter of
the median pressure that gives the LuGre position's p_l. It follows a creep without lag, passes
the rope bounce it models with little loss where a low-pass of the same noise would not, its
stated noise gain is what white noise gets through it, and settings the node cannot hold are
refused with the field named."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ropemon.commission.nodejson import example_physical, physical_params, tracker_gains
from ropemon.commission.reference import PressureTracker

FS = 200.0
R = (0.546 * 5e3) ** 2  # the median of four 5 kPa channels


def run(tr: dict, y: np.ndarray) -> np.ndarray:
    t = PressureTracker(tr)
    return np.array([t.step(v) for v in y.tolist()])


def amplitude_and_lag(y: np.ndarray, f: float) -> tuple[float, float]:
    """Amplitude and phase (rad, positive: behind) of y's component at f (whole periods)."""
    t = np.arange(len(y)) / FS
    c = 2 * np.mean(y * np.exp(-2j * np.pi * f * t))
    return abs(c), -np.angle(c) - np.pi / 2  # against sin(2 pi f t)


@pytest.fixture(scope="module")
def tr() -> dict:
    return tracker_gains(FS, 2.8, 0.2, 3e9, 3e9, R)


def test_a_creep_is_followed_without_lag(tr):
    # 9 MPa, then a ramp of 100 kPa/s for 5 s: the creep model's estimate has no steady lag
    # (a one-pole low-pass at 5 Hz lags such a ramp by 3.2 kPa)
    t = np.arange(int(8 * FS)) / FS
    y = 9e6 + 1e5 * np.clip(t - 1, 0, 5)
    out = run(tr, y)
    late = (t > 4) & (t < 6)
    assert np.max(np.abs(out[late] - y[late])) < 1.0  # Pa
    assert np.max(np.abs(out[t > 7.5] - y[t > 7.5])) < 1.0


def test_the_bounce_passes_at_about_unity_where_a_low_pass_of_the_same_noise_shrinks_it(tr):
    # the modelled bounce band (1-4 Hz) passes at 1.0-1.1, about 20 degrees behind at
    # 2.8 Hz; a one-pole low-pass that lets through as much white noise passes 0.92 there
    f = 2.8
    t = np.arange(int(20 * FS)) / FS
    out = run(tr, 9e6 + 1e3 * np.sin(2 * np.pi * f * t))[int(10 * FS):]
    amp, lag = amplitude_and_lag(out - 9e6, f)
    assert 1.0 < amp / 1e3 < 1.1
    assert 0 < lag < math.radians(25)
    g2 = tr["noise_gain"] ** 2
    alpha = 2 * g2 / (1 + g2)  # alpha / (2 - alpha) = g**2
    w = 2 * math.pi * f / FS
    lp = abs(alpha / (1 - (1 - alpha) * complex(math.cos(w), -math.sin(w))))
    assert lp < 0.95 < amp / 1e3
    # well above the band it attenuates (the noise's share)
    out = run(tr, 9e6 + 1e3 * np.sin(2 * np.pi * 12.0 * t))[int(10 * FS):]
    assert amplitude_and_lag(out - 9e6, 12.0)[0] / 1e3 < 0.5


def test_its_noise_gain_is_what_white_noise_gets_through(tr):
    rng = np.random.default_rng(3)
    y = 9e6 + rng.normal(0, 2.7e3, int(60 * FS))
    out = run(tr, y)[int(5 * FS):]
    assert np.std(out) / 2.7e3 == pytest.approx(tr["noise_gain"], rel=0.05)
    assert 0.2 < tr["noise_gain"] < 0.6


def test_the_gains_are_held_as_the_node_holds_them(tr):
    assert 0 < tr["a2_q14"] < 16384 and 0 < tr["a1_q14"] < 32768
    assert all(abs(k) <= 16384 for k in tr["k_q14"])
    assert 0 <= tr["v_shift"] <= 12 and 0 <= tr["b_shift"] <= 5
    # the rate's and the bounce's gains are small: they use the finer scales, with at
    # least 12 of the 14 bits (or the finest scale there is)
    assert abs(tr["k_q14"][1]) >= 1 << 12 or tr["v_shift"] == 12
    assert max(abs(k) for k in tr["k_q14"][2:]) >= 1 << 12 or tr["b_shift"] == 5


def test_the_node_tracker_follows_the_float_one_within_a_few_pascal():
    """The node's integer tracker (kernel.step, plain kernel) against PressureTracker fed
    the same median (the node's own, from its kPa/16 channels): rounding only, no drift
    (the creep's rate is held 2**v_shift finer than the creep: at the creep's own
    resolution its rounding walked the estimate by up to ~100 Pa)."""
    import array

    from ropemon.firmware import node_module
    from ropemon.commission.nodejson import make_node_json
    kernel = node_module("kernel")
    ph = dict(example_physical(), hydraulic_compliance_m_per_Pa=[3e-10] * 4)
    doc = make_node_json(ph)
    tr = physical_params(doc["physical"])["tracker"]
    node = node_module("node").Node(node_module("config").parse(doc), step=kernel.step)
    n_ropes = ph["ropes"]
    rng = np.random.default_rng(7)
    n = int(40 * FS)
    t = np.arange(n) / FS
    y = 7e6 + 1e5 * np.sin(0.3 * t) + 3e3 * np.sin(2 * np.pi * 2.8 * t)
    rec = array.array("H", bytes(2 * (2 * n_ropes + 4)))
    got, med = [], []
    for j in range(n):
        for i in range(n_ropes):
            pc, dc = ph["pressure_channels"][i], ph["displacement_channels"][i]
            lo, hi = pc["range_Pa"]
            c = pc["counts_4mA"] + (y[j] + rng.normal(0, 2.8e3) - lo) / (hi - lo) * (pc["counts_20mA"] - pc["counts_4mA"])
            rec[i] = int(round(c))
            rec[n_ropes + i] = (dc["counts_lo"] + dc["counts_hi"]) // 2
        rec[2 * n_ropes + 1] = 0xFFFF
        node.sample(rec)
        kpa16 = sorted(node.S[kernel.P_KPA16 + i] for i in range(n_ropes))
        med.append((kpa16[1] + kpa16[2]) / 32 * 1e3)  # the node's median, Pa
        got.append(node.S[kernel._PL_Q8] / 256 * 1e3)
    want = run(tr, np.array(med))
    d = (np.array(got) - want)[int(FS):]
    assert np.abs(d).max() < 10.0 and abs(d.mean()) < 1.0, (np.abs(d).max(), d.mean())


def test_the_node_section_carries_the_tracker_only_with_a_compliance():
    ph = example_physical()
    assert physical_params(ph)["tracker"] is None
    k = dict(ph, hydraulic_compliance_m_per_Pa=[3e-10] * ph["ropes"])
    pp = physical_params(k)
    assert pp["tracker"]["a1_q14"] > 0
    # a faster bounce model is a different filter
    assert physical_params(dict(k, bounce_hz=4.0))["tracker"]["a1_q14"] < pp["tracker"]["a1_q14"]


@pytest.mark.parametrize("key,value,field", [
    ("bounce_hz", 0.1, "physical.bounce_hz"),
    ("bounce_hz", 30.0, "physical.bounce_hz"),          # above sample_hz / 8
    ("bounce_filter_damping", 0.0, "physical.bounce_filter_damping"),
    ("creep_q_Pa2_s3", -1.0, "physical.creep_q_Pa2_s3"),
    ("bounce_q_Pa2_s3", "3e9", "physical.bounce_q_Pa2_s3"),
    ("pressure_cutoff_hz", 5.0, "physical.pressure_cutoff_hz"),  # the low-pass it replaced
])
def test_bad_tracker_settings_are_refused_with_the_field(key, value, field):
    ph = dict(example_physical(), hydraulic_compliance_m_per_Pa=[3e-10] * 4)
    ph[key] = value
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        physical_params(ph)
