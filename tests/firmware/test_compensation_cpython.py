"""Fixed-point node vs the float64 reference (ropemon.commission.reference) on long random streams.

Streams cover the full pressure and displacement ranges: rest, slow creep,
oscillation with reversals, random walks, shock steps, v_max saturation, and
NAMUR faults. Bound: max |T_fixed - T_ref| <= 0.05 % of the rated rope tension.
"""
from __future__ import annotations

import numpy as np
import pytest
from streams_cpython import random_stream, run_node, slide_stream, wind_records

from ropemon.station import protocol
from ropemon.commission import reference
from ropemon.firmware import node_module
from ropemon.commission.nodejson import COMPLIANCE_DEFAULTS, example_physical, make_node_json, namur_limits

config = node_module("config")
Node = node_module("node").Node
L = node_module("layout")


def _doc(**changes):
    ph = example_physical()
    ph.update(changes)
    return make_node_json(ph)


def _tolerance_n(doc) -> float:
    return 0.0005 * doc["physical"]["rated_rope_tension_N"]


@pytest.mark.parametrize("seed,faults,step_check", [(1, False, False), (2, False, False), (3, True, False),
                                                    (4, True, True)])
def test_fixed_point_matches_reference_per_sample(seed, faults, step_check):
    """The streams' pressure shocks (a few MPa within a sample) are implausible steps: with
    the check (the shipped default) node and reference fault the same samples; without it
    (pressure_step_max_Pa 0) the compensation sees the shocks."""
    doc = _doc() if step_check else _doc(pressure_step_max_Pa=0.0)
    ph = doc["physical"]
    recs = random_stream(ph, 45, seed, faults=faults)
    ref = reference.compensate(ph, recs)
    ten, good, _ = run_node(Node(config.parse(doc)), recs)
    assert (good == ref.good).all()
    assert good.mean() > (0.8 if step_check else 0.9 if faults else 0.99)
    err = np.abs(ten - ref.tension_n)[good]
    assert err.max() <= _tolerance_n(doc), err.max()
    # the stream did exercise friction and loss, so the bound means something
    assert np.abs(ref.friction_n).max() > 10000 and np.abs(ref.loss_n).max() > 1000
    assert (np.abs(ref.v_m_s) >= 0.2 - 1e-9).any()  # saturated velocity reached
    stribeck = (np.abs(ref.v_m_s) > 2e-4) & (np.abs(ref.v_m_s) < 1e-2)
    assert stribeck.mean() > 0.05  # steady sliding where g(v) is curved


def test_fixed_point_matches_reference_with_temperature_input():
    doc = _doc(temperature={"counts_at_0C": 17280, "counts_per_C": 384.0})
    ph = doc["physical"]
    recs = random_stream(ph, 30, 11)
    k = recs.shape[0]
    temp_c = 40 * np.sin(np.linspace(0, 6, k)) + 10  # -30 .. 50 C: clamps at both table ends
    recs[:, 2 * 4 + 1] = np.round(17280 + 384 * temp_c).astype(np.uint16)
    ref = reference.compensate(ph, recs)
    ten, good, frames = run_node(Node(config.parse(doc)), recs)
    err = np.abs(ten - ref.tension_n)[good]
    assert err.max() <= _tolerance_n(doc), err.max()
    f = protocol.decode_raw(protocol.decode_wire(frames[-1][:-1]))
    assert f.oil_temp_cc != L.OIL_TEMP_ABSENT and not f.status & L.ST_TEMP_ABSENT


def test_frames_match_reference_decimation_and_authenticate():
    doc = _doc()
    ph = doc["physical"]
    recs = random_stream(ph, 30, 4, faults=True)
    ref = reference.compensate(ph, recs)
    dec = reference.decimate(ph, ref)
    _, _, frames = run_node(Node(config.parse(doc)), recs, per_sample=False)
    assert len(frames) == dec.mean_n.shape[0]
    key = bytes(doc["node"]["key"])
    tol_dan = _tolerance_n(doc) / 10 + 1  # + rounding to whole daN
    absent = 0
    for j, wire in enumerate(frames):
        assert len(wire) <= L.MAX_WIRE_LEN
        f = protocol.decode_raw(protocol.decode_wire(wire[:-1]), keys={doc["node"]["node_id"]: key})
        assert f.authenticated and f.seq == j and f.time_ms == (j + 1) * 100
        for i, r in enumerate(f.ropes):
            if np.isnan(dec.mean_n[j, i]):
                assert r.mean_dan == L.TENSION_ABSENT and r.raw_kpa == L.RAW_KPA_ABSENT
                assert f.fault_mask & (0x11 << i)
                absent += 1
                continue
            assert abs(r.mean_dan - dec.mean_n[j, i] / 10) <= tol_dan
            assert abs(r.min_dan - dec.min_n[j, i] / 10) <= tol_dan
            assert abs(r.max_dan - dec.max_n[j, i] / 10) <= tol_dan
            assert abs(r.raw_kpa - dec.raw_pa[j, i] / 1000) <= 2
    # faults were in the stream and showed in the masks
    masks = [protocol.decode_raw(protocol.decode_wire(w[:-1])).fault_mask for w in frames]
    assert sum(1 for m in masks if m) > len(frames) // 4


def test_frame_positions_and_stroke_bits_match_a_float_calculation():
    """Each frame's pos_01mm, stroke_mask and displacement fault bits, decoded by the host,
    against the same in float64 from the physical section: the channel's linear calibration
    (from mid-stroke), its NAMUR limits, the end stops at +-stroke/2, the margin and the travel
    tolerance. Positions within 0.1 mm (rounding); bits equal, except for a rope whose window
    had a reading within 1 um of a limit (the node's calibration is rounded)."""
    doc = _doc(stroke_m=[0.08] * 4)  # end stops at +-40 mm: the stream's +-50 mm goes beyond the travel
    ph = doc["physical"]
    n = ph["ropes"]
    recs = np.concatenate([random_stream(ph, 30, seed, faults=True) for seed in (21, 22, 23)])
    _, _, frames = run_node(Node(config.parse(doc)), recs, per_sample=False)
    win = ph["sample_hz"] // ph["frame_hz"]
    m, tol = ph["stroke_margin_m"], ph["travel_tolerance_m"]
    err = []
    seen = {"low": 0, "high": 0, "travel": 0, "near": 0}
    assert len(frames) == len(recs) // win
    for j, wire in enumerate(frames):
        f = protocol.decode_raw(protocol.decode_wire(wire[:-1]))
        assert f.version == 3 and bool(f.status & L.ST_STROKE_LIMIT) == (f.stroke_mask != 0)
        for i in range(n):
            dc = ph["displacement_channels"][i]
            clo, chi = dc["counts_lo"], dc["counts_hi"]
            ylo, yhi = dc["range_m"]
            flo, fhi = namur_limits(clo, chi)
            c = recs[j * win:(j + 1) * win, n + i].astype(float)
            x = ylo + (c - clo) * (yhi - ylo) / (chi - clo)
            half = ph["stroke_m"][i] / 2
            lims = np.array([-half - tol, -half + m, half - m, half + tol])
            inside = (c >= flo) & (c <= fhi)
            ok = inside & (x >= lims[0]) & (x <= lims[3])
            if (np.abs(x[inside][:, None] - lims) < 1e-6).any():
                seen["near"] += 1
                continue
            assert bool(f.fault_mask & (16 << i)) == (not ok.all()), (j, i)
            seen["travel"] += int((inside & ~ok).any())
            low = bool((x[ok] <= lims[1]).any())
            high = bool((x[ok] >= lims[2]).any())
            assert (bool(f.stroke_mask & (1 << i)), bool(f.stroke_mask & (16 << i))) == (low, high), (j, i)
            seen["low"] += low
            seen["high"] += high
            pos = f.ropes[i].pos_01mm
            if ok.any():
                err.append(pos - x[ok].mean() * 1e4)
                assert f.ropes[i].position_m == pos * 1e-4
            else:
                assert pos == L.POS_ABSENT and f.ropes[i].position_m is None
    assert max(abs(e) for e in err) <= 0.55, max(abs(e) for e in err)
    # the stream took pistons into both margins and beyond the travel
    assert seen["low"] > 5 and seen["high"] > 5 and seen["travel"] > 5, seen
    assert seen["near"] < len(frames) * n // 20, seen


def test_peaks_survive_decimation():
    doc = _doc()
    ph = doc["physical"]
    recs = random_stream(ph, 2, 5)
    recs[:, 0] = 20000
    recs[:, 4] = 30000
    recs[113, 0] = 21700  # one-sample shock on rope 0, 1.1 MPa: within the plausible step (1786 counts)
    _, _, frames = run_node(Node(config.parse(doc)), recs, per_sample=False)
    f = protocol.decode_raw(protocol.decode_wire(frames[113 // 20][:-1]))
    assert f.fault_mask & 1 == 0
    shock_dan = (21700 - 9600) * 25e6 / 38400 * 0.00785398 / 10
    assert abs(f.ropes[0].max_dan - shock_dan) < 2
    assert f.ropes[0].mean_dan < f.ropes[0].max_dan - 500


def _glitch_run(doc, recs):
    ten, good, frames = run_node(Node(config.parse(doc)), recs)
    return ten, good, [protocol.decode_raw(protocol.decode_wire(w[:-1])) for w in frames]


def test_an_implausible_pressure_step_is_a_fault_until_plausible_again():
    """A transmitter glitch of 10 MPa for one sample on rope 1 of a steady wind (compliance,
    strokes tracked): the node faults rope 1 from the glitch until its steps have been
    plausible for step_recover samples (fault_mask bit 1, pressure_fault, no tension), as
    the reference does, and the bad value reaches neither its tension nor the others' (the
    median, the tracker). Without the check (pressure_step_max_Pa 0) it does."""
    ph = example_physical()
    ph["hydraulic_compliance_m_per_Pa"] = [3e-10] * 4
    fs = ph["sample_hz"]
    t = np.arange(0, 12, 1 / fs)
    p_pa = 6e6 + 2e5 * np.sin(2 * np.pi * 0.3 * t)  # 0.38 MPa/s: well within the limit
    x = 3e-10 * (p_pa - p_pa[0])[:, None] * np.ones(4)
    clean = wind_records(ph, p_pa, x, 3)
    recs = clean.copy()
    at = 8 * fs + 7
    recs[at, 1] += round(10e6 / 25e6 * 38400)  # 10 MPa for one sample, inside NAMUR
    doc = _doc(**{k: v for k, v in ph.items() if k not in example_physical()})
    nd = doc["node"]
    assert nd["pressure"][1]["step_max_counts"] == 1786 and nd["step_recover"] == 20
    ten0, good0, _ = _glitch_run(doc, clean)
    ten, good, frames = _glitch_run(doc, recs)
    bad = np.flatnonzero(~good[:, 1])
    assert list(bad) == list(range(at, at + 21))  # the glitch, its return and 19 more samples
    assert good[:, [0, 2, 3]].all()
    ref = reference.compensate(doc["physical"], recs)
    assert (ref.good == good).all()
    assert (ref.fault_mask[at:at + 21] == 2).all() and ref.fault_mask[at + 21] == 0
    err = np.abs(ten - ref.tension_n)[good]
    assert err.max() <= _tolerance_n(doc), err.max()
    f = frames[at // 20]
    assert f.fault_mask == 2 and f.status & L.ST_PRESSURE_FAULT
    assert not frames[at // 20 + 2].fault_mask
    # the others never saw it: their tension as on the clean stream, but for the play of
    # three channels' median for those 21 samples (a few N)
    assert np.abs(ten - ten0)[:, [0, 2, 3]].max() < 50
    # without the check the glitch is 78 kN of tension on rope 1 and reaches the others
    off = _doc(**{k: v for k, v in ph.items() if k not in example_physical()}, pressure_step_max_Pa=0.0)
    ten1, good1, frames1 = _glitch_run(off, recs)
    assert good1.all() and not any(f.fault_mask for f in frames1)
    assert ten1[at, 1] - ten0[at, 1] > 70000


@pytest.mark.parametrize("sigma0", [2e7, 1e8])
def test_fixed_point_matches_reference_with_noisy_displacement(sigma0):
    """Displacement noise of 2 counts rms (the default channel's 20 um) on held, creeping and
    reversing pistons: the LuGre filter, play and bound take the same path in both."""
    ph = example_physical()
    ph["friction"] = dict(ph["friction"], sigma0=sigma0, sigma1=sigma0 * 1e-3)
    ph["piston_speed_max_m_s"] = 0.05  # sigma0 dx_max stays within the node's 2**19 (N/16)
    doc = make_node_json(ph)
    ph = doc["physical"]
    recs = random_stream(ph, 30, 12)
    rng = np.random.default_rng(12)
    x = recs[:, 4:8].astype(float) + rng.normal(0, 2.0, (recs.shape[0], 4))
    recs[:, 4:8] = np.clip(np.round(x), 0, 65535).astype(np.uint16)
    ref = reference.compensate(ph, recs)
    ten, good, _ = run_node(Node(config.parse(doc)), recs)
    err = np.abs(ten - ref.tension_n)[good]
    assert err.max() <= _tolerance_n(doc), err.max()
    assert np.abs(ref.friction_n).max() > 0.5 * sigma0 * 1e-4  # the seal state moved


@pytest.mark.parametrize("seed,faults", [(21, False), (22, True)])
def test_fixed_point_matches_reference_with_hydraulic_compliance(seed, faults):
    """With a compliance the LuGre position is k p_l + b (pressure low-pass, slow b, its
    warm-up): the same path in both, on random streams with pressure noise and faults."""
    ph = example_physical()
    ph["hydraulic_compliance_m_per_Pa"] = [3e-10, 2.5e-10, 3.2e-10, 3e-10]
    ph["friction"] = dict(ph["friction"], sigma0=1e8, sigma1=1e5)
    ph["piston_speed_max_m_s"] = 0.05
    doc = make_node_json(ph)
    ph = doc["physical"]
    assert doc["node"]["friction"]["compliance_q"][0] > 0
    assert doc["node"]["friction"]["warmup_samples"] == 400
    recs = random_stream(ph, 30, seed, faults=faults)
    rng = np.random.default_rng(seed)
    p = recs[:, 0:4].astype(float) + rng.normal(0, 3.0, (recs.shape[0], 4))
    recs[:, 0:4] = np.clip(np.round(p), 0, 65535).astype(np.uint16)
    ref = reference.compensate(ph, recs)
    ten, good, _ = run_node(Node(config.parse(doc)), recs)
    assert (good == ref.good).all()
    err = np.abs(ten - ref.tension_n)[good]
    assert err.max() <= _tolerance_n(doc), err.max()
    assert np.abs(ref.friction_n).max() > 5000  # the seal state moved


def _compression_records(ph: dict, p_pa: np.ndarray, k_m: float, x_noise_counts: float = 0.0) -> np.ndarray:
    """Records of every rope at pressure p_pa (Pa) whose piston moves only as its oil
    compresses (x = mid-range + k dp), on ph's channels; no oil temperature input."""
    n = int(ph["ropes"])
    recs = np.zeros((len(p_pa), 2 * n + 4), np.uint16)
    for i in range(n):
        pc, dc = ph["pressure_channels"][i], ph["displacement_channels"][i]
        lo, hi = pc["range_Pa"]
        recs[:, i] = np.round(pc["counts_4mA"] + (p_pa - lo) / (hi - lo) * (pc["counts_20mA"] - pc["counts_4mA"]))
        ylo, yhi = dc["range_m"]
        x = 0.5 * (ylo + yhi) + k_m * (p_pa - p_pa[0])
        cx = dc["counts_lo"] + (x - ylo) / (yhi - ylo) * (dc["counts_hi"] - dc["counts_lo"])
        if x_noise_counts:
            cx = cx + np.random.default_rng(i).normal(0, x_noise_counts, len(p_pa))
        recs[:, n + i] = np.round(cx)
    recs[:, 2 * n + 1] = 0xFFFF
    return recs


def test_with_a_compliance_the_loss_and_viscous_terms_take_the_pressure_velocity():
    """At constant pressure with the displacement channel's 2-count noise, the filtered
    piston velocity still swings by hundreds of um/s. With a compliance the pipe loss
    and the viscous term sigma2 v take the LuGre position's velocity (from the pressure)
    and stay quiet; without one they take the filtered velocity and pass its noise."""
    ph = example_physical()
    fs = int(ph["sample_hz"])
    k_m = 3e-10
    p_pa = np.full(10 * fs, 4e6)
    recs = _compression_records(ph, p_pa, k_m, x_noise_counts=2.0)
    after = slice(3 * fs, None)  # past the warm-up
    no_k = reference.compensate(ph, recs)
    ph_k = dict(ph, hydraulic_compliance_m_per_Pa=[k_m] * 4)
    for key in COMPLIANCE_DEFAULTS:
        ph_k.pop(key, None)
    with_k = reference.compensate(ph_k, recs)
    s2 = ph["friction"]["sigma2"]["intercept"] + 4.0 * ph["friction"]["sigma2"]["slope"]
    assert np.std(no_k.v_m_s[after, 0]) > 1e-4  # the filtered velocity is noisy
    assert np.std(no_k.loss_n[after, 0]) > 0.5
    assert np.std(with_k.loss_n[after, 0]) < 0.05 * np.std(no_k.loss_n[after, 0])
    # the viscous part of the friction, sigma2 times the velocity it is given, from one
    # sample to the next (the seal state itself wanders only slowly)
    noise_n = s2 * np.std(np.diff(no_k.v_m_s[after, 0]))
    assert noise_n > 2.0
    assert np.std(np.diff(with_k.friction_n[after, 0])) < 0.1 * noise_n


def test_compliance_drives_the_seal_state_from_pressure():
    """A piston that moves only as its oil compresses (x = k p, with the displacement
    channel's 2-count noise): with k, the seal state follows the pressure ramp to sliding
    friction, and holds still while the pressure does. With the observer a site with a
    compliance gets (b at 0.03 Hz, the play of COMPLIANCE_DEFAULTS)."""
    ph = example_physical()
    ph["friction"] = dict(ph["friction"], sigma0=1e8, sigma1=1e5)
    ph["piston_speed_max_m_s"] = 0.05
    for key in COMPLIANCE_DEFAULTS:
        ph.pop(key, None)
    n = 4
    fs = int(ph["sample_hz"])
    k_m = 3e-10
    t = np.arange(0, 20, 1 / fs)
    p_pa = 4e6 + 1e6 * np.clip((t - 5) / 5, 0, 1)  # a loading: 4 -> 5 MPa over 5 s
    recs = _compression_records(ph, p_pa, k_m, x_noise_counts=2.0)
    with_k = reference.compensate(dict(ph, hydraulic_compliance_m_per_Pa=[k_m] * n), recs)
    # the elastic seal state follows k dp = 300 um of travel: sigma0 x 300 um is far above
    # Fs, so the seal slides and its friction reaches g (Fs at creep speed)
    f_end = with_k.friction_n[-1, 0]
    g_end = ph["friction"]["Fs"]["intercept"] + ph["friction"]["Fs"]["slope"] * 5.0
    assert 0.8 * g_end < f_end <= 1.01 * g_end, (f_end, g_end)
    # before the loading the pressure is constant: only b's slow wander of the 20 um
    # displacement noise (~0.4 um rms at 0.03 Hz, x sigma0) moves the seal state
    assert np.abs(with_k.friction_n[: 4 * fs, 0]).max() < 300


def test_a_pressure_loop_fault_restarts_the_lugre_position_not_the_seal_state():
    """A pressure loop that fails for 2 s while the load rises by 1 MPa: on its return
    the node starts its position filters again (with the warm-up) instead of taking the
    1 MPa step as k dp = 300 um of seal travel; the seal state from before is kept."""
    ph = example_physical()
    ph["friction"] = dict(ph["friction"], sigma0=1e8, sigma1=1e5)
    ph["piston_speed_max_m_s"] = 0.05
    ph["hydraulic_compliance_m_per_Pa"] = [3e-10] * 4
    doc = make_node_json(ph)
    ph = doc["physical"]
    fs = int(ph["sample_hz"])
    t = np.arange(0, 12, 1 / fs)
    # a pull, then a load change in the fault: 1 MPa in 0.5 s (a load does not come on within one
    # sample; the pressure tracker would overshoot such a step by 14 %, docs/model.md)
    p_pa = 4e6 + 0.3e6 * np.clip((t - 1) / 2, 0, 1) + 1e6 * np.clip((t - 5.75) / 0.5, 0, 1)
    recs = _compression_records(ph, p_pa, 3e-10)
    fault = (t >= 5) & (t < 7)
    recs[fault, 0] = 0  # rope 1's loop below 3.6 mA
    ref = reference.compensate(ph, recs)
    ten, good, _ = run_node(Node(config.parse(doc)), recs)
    assert not good[fault, 0].any() and good[~fault, 0].all()
    err = np.abs(ten - ref.tension_n)[good]
    assert err.max() <= _tolerance_n(doc), err.max()
    before = ref.friction_n[int(4.9 * fs), 0]
    assert before > 3000  # the pull built a holding friction
    after = ref.friction_n[int(7.5 * fs):, 0]
    assert np.abs(after - before).max() < 100, (before, after.min(), after.max())
    # the other ropes, whose loops stayed healthy, followed the 1 MPa step as seal travel
    assert ref.friction_n[int(7.5 * fs), 1] > before + 500  # (to sliding friction)


def _stroke_wind(ph: dict, k_m: float, seed: int, stroke: bool = True):
    """(records, true positions, pressure) of a balancing stroke, as the 50-wind duty cycle
    has them (notes/accuracy-research.md, "The duty cycle"): the pressure falls at 55 kPa/s for 20 s (the oil
    decompresses, the pistons share the common motion 4 k dp), from 12 s on rope 1's piston
    alone takes it while the others stick, and at 26 s the fall turns into a rise with a
    2 Hz bounce that all four pistons share again. 2 counts of displacement noise."""
    n = int(ph["ropes"])
    fs = int(ph["sample_hz"])
    t = np.arange(0, 32, 1 / fs)
    p_pa = 5e6 - 55e3 * np.clip(t - 6, 0, 20)
    after = np.clip(t - 26, 0, None)
    p_pa = p_pa + np.where(t >= 26, 2e5 * np.minimum(after, 1) + 2e4 * np.sin(2 * np.pi * 2 * after), 0)
    dmove = n * k_m * np.diff(p_pa, prepend=p_pa[0])  # the common motion of one sample
    share = np.full((len(t), n), 1 / n)
    alone = (t >= 12) & (t < 26) & stroke
    share[alone] = 0.0
    share[alone, 0] = 1.0
    x = np.cumsum(dmove[:, None] * share, axis=0)
    return wind_records(ph, p_pa, x, seed), x, p_pa


def _stroke_doc(k_m: float) -> dict:
    """The node.json of the stroke wind: a stiff seal (sigma0 1e8 N/m), pistons up to
    5 cm/s, compliance k_m on every rope and the observer a site with one gets."""
    ph = example_physical()
    ph["friction"] = dict(ph["friction"], sigma0=1e8, sigma1=1e5)
    ph["piston_speed_max_m_s"] = 0.05
    ph["hydraulic_compliance_m_per_Pa"] = [k_m] * 4
    for key in COMPLIANCE_DEFAULTS:
        ph.pop(key, None)
    return make_node_json(ph)


def _true_friction(ph: dict, x: np.ndarray, p_pa: np.ndarray) -> np.ndarray:
    """The seal's LuGre friction along the true positions (testbed.LuGre, 8 sub-steps)."""
    from ropemon.lab.testbed import LuGre

    fs = int(ph["sample_hz"])
    out = np.empty(x.shape)
    for i in range(x.shape[1]):
        law = LuGre(ph["friction"])
        v = np.gradient(x[:, i]) * fs
        for j, (vj, pj) in enumerate(zip(v.tolist(), (p_pa / 1e6).tolist())):
            for _ in range(8):
                law.force(vj, pj, 1 / fs / 8)
            out[j, i] = law.force(vj, pj, 0.0)
    return out


@pytest.mark.parametrize("seed", [31, 32])
def test_a_balancing_stroke_is_followed_and_the_bounce_after_it_seen(seed):
    """One piston takes the whole common motion for 14 s while the others stick (a
    balancing stroke): the node sees it in the displacement, gives that rope the motion
    the pressure says, holds the others still, and after the stroke reads the bounce that
    relaxes the seals nearly as well as when there was no stroke. Without stroke tracking
    (stroke_sigmas 0) b's 0.03 Hz lag puts the seal states kN off in the bounce. Fixed
    point and reference agree on both."""
    k_m = 3e-10
    ph = example_physical()
    # friction lines flat in pressure: a stuck piston then holds its friction exactly
    # (_true_friction does not let it slip as g(p) falls)
    ph["friction"] = dict(ph["friction"], sigma0=1e8, sigma1=1e5,
                          **{key: {"intercept": ph["friction"][key]["intercept"] + 4.5 * ph["friction"][key]["slope"],
                                   "slope": 0.0} for key in ("Fs", "Fc")})
    ph["piston_speed_max_m_s"] = 0.05
    ph["hydraulic_compliance_m_per_Pa"] = [k_m] * 4
    for key in COMPLIANCE_DEFAULTS:  # the observer a site with a compliance gets
        ph.pop(key, None)
    doc = make_node_json(ph)
    ph = doc["physical"]
    assert doc["node"]["friction"]["stroke_q8um"] > 0
    fs = int(ph["sample_hz"])
    recs, x, p_pa = _stroke_wind(ph, k_m, seed)
    truth = _true_friction(ph, x, p_pa)
    rms = {}
    for sigmas in (None, 0.0):
        phv = ph if sigmas is None else dict(ph, stroke_sigmas=sigmas)
        docv = doc if sigmas is None else make_node_json(phv)
        ref = reference.compensate(phv, recs)
        ten, good, _ = run_node(Node(config.parse(docv)), recs)
        err = np.abs(ten - ref.tension_n)[good]
        assert err.max() <= _tolerance_n(docv), err.max()
        after = slice(26 * fs, None)  # the bounce after the stroke
        rms[sigmas] = np.sqrt(np.mean((ref.friction_n[after] - truth[after]) ** 2))
    # the floor: the same wind without the stroke (the pistons share the motion throughout)
    recs, x, p_pa = _stroke_wind(ph, k_m, seed, stroke=False)
    truth = _true_friction(ph, x, p_pa)
    floor = np.sqrt(np.mean((reference.compensate(ph, recs).friction_n[after] - truth[after]) ** 2))
    # seed 31: 290 N with tracking, 254 N without the stroke, 2038 N untracked (Fs 6 kN)
    assert rms[None] < 1.5 * floor and rms[None] < 0.06 * ph["friction"]["Fs"]["intercept"], (rms, floor)
    assert rms[0.0] > 4 * rms[None], rms


@pytest.mark.parametrize("seed", [61, 62])
def test_differential_sliding_outside_a_stroke_is_seal_travel_with_slide_following(seed):
    """Two pistons part by 1 mm over 20 s (25 um/s each way, the oil they share kept) while
    the pressure rises 1 MPa: rope 2's piston moves back against its compression, so its
    seal slides the other way. Its e stays below the stroke threshold (no stroke), and
    what x_h takes over from e is proven travel beyond 3 .. 5 sigma of e's noise: with
    slide following (the default) the seal state follows (rope 2's friction 1.1 kN rms
    off the true seal's, against 8.2 kN without: it never sees the reversal). Node and
    reference agree with it on and off."""
    k_m = 3e-10
    ph = example_physical()
    ph["friction"] = dict(ph["friction"], sigma0=1e8, sigma1=1e5,
                          **{key: {"intercept": ph["friction"][key]["intercept"] + 4.5 * ph["friction"][key]["slope"],
                                   "slope": 0.0} for key in ("Fs", "Fc")})
    ph["piston_speed_max_m_s"] = 0.05
    ph["hydraulic_compliance_m_per_Pa"] = [k_m] * 4
    for key in COMPLIANCE_DEFAULTS:  # the observer a site with a compliance gets
        ph.pop(key, None)
    doc = make_node_json(ph)
    ph = doc["physical"]
    fr = doc["node"]["friction"]
    # lo and hi - lo: 3 and 2 times e's noise, the stroke threshold 6.5 times it
    assert abs(fr["slide_lo_q8um"] / fr["stroke_q8um"] - 3 / 6.5) < 0.01
    assert abs(fr["slide_span_q8um"] / fr["stroke_q8um"] - 2 / 6.5) < 0.01
    fs = int(ph["sample_hz"])
    recs, x, p_pa = slide_stream(ph, k_m, seed, slide_um_s=25.0)
    truth = _true_friction(ph, x, p_pa)
    fric, rms = {}, {}
    for on in (True, False):
        phv = dict(ph, slide_follow=on)
        docv = make_node_json(phv)
        assert (docv["node"]["friction"]["slide_span_q8um"] > 0) == on
        strokes = []
        ref = reference.compensate(phv, recs, strokes=strokes)
        assert strokes == []  # differential sliding, not a stroke
        node = Node(config.parse(docv))
        ten, good, _ = run_node(node, recs)
        assert good[fs:].all()
        err = np.abs(ten - ref.tension_n)[good]
        assert err.max() <= _tolerance_n(docv), (on, err.max())
        fric[on] = ref.friction_n
        after = slice(6 * fs, None)
        rms[on] = np.sqrt(np.mean((ref.friction_n[after] - truth[after]) ** 2, axis=0))
    assert np.abs(fric[True] - fric[False]).max() > 5000  # the option visibly changes the output
    assert rms[True][1] < 0.2 * rms[False][1] and rms[True][1] < 1500, rms
    assert rms[True][0] < rms[False][0], rms  # rope 1 slides on with its compression: no worse
    assert np.abs(rms[True][2:] - rms[False][2:]).max() < 1.0, rms  # the ropes that share stay as they were


def test_node_and_reference_take_the_same_stroke_at_the_same_sample():
    """`ropemon study stroke-events`' two sides on the stroke wind: the reference's `strokes`
    list and the node's kernel state agree on when rope 1's stroke starts and ends."""
    from ropemon.lab.studies import stroke_events as tool

    k_m = 3e-10
    doc = _stroke_doc(k_m)
    recs, _x, _p = _stroke_wind(doc["physical"], k_m, 33)
    ref = []
    reference.compensate(doc["physical"], recs, strokes=ref)
    node = tool.node_strokes(doc, recs)
    fs = int(doc["physical"]["sample_hz"])
    assert [(j, r) for j, r, _ in ref] == [(j, r) for j, r, _ in node]
    (start, rope, e_start), (end, ended, _e) = ref
    assert rope == 0 and ended == -1
    assert 12 * fs < start < 13.5 * fs and 26 * fs <= end < 26.5 * fs, (start / fs, end / fs)
    assert e_start[0] < -doc["node"]["friction"]["stroke_q8um"] / 256e6  # rope 1 ran ahead downwards


def test_at_a_stroke_start_the_stopped_pistons_are_placed_where_they_stopped():
    """Until a stroke is seen (its e past the threshold, about 0.7 s in), the LuGre
    positions x_h of the pistons that stopped go on with the pressure. At the start the
    node puts them back by the stroke piston's lead shared by area plus the low-pass lag
    of e (docs/model.md, "Balancing strokes"), not by their own e: after the start sample
    their x_h is -0.01 um off the true position on average, 0.37 um rms (re-anchored by
    their own e, as the node did before: +0.86 um, 1.07 um rms), with no seal travel.
    Over 12 seeds of the stroke wind, 3 stopped ropes each."""
    import array

    kernel = node_module("kernel")
    k_m = 3e-10
    doc = _stroke_doc(k_m)
    offsets = []
    for seed in range(40, 52):
        recs, x, _p = _stroke_wind(doc["physical"], k_m, seed)
        node = Node(config.parse(doc))
        S = node.S
        rec = array.array("H", [0] * recs.shape[1])
        for j, row in enumerate(recs.tolist()):
            rec[:] = array.array("H", row)
            xs = [S[kernel.XS_Q8UM + i] for i in range(4)]
            node.sample(rec)
            if S[kernel._SMODE] == 1:  # rope 1's stroke has just started
                break
        else:
            raise AssertionError(f"seed {seed}: no stroke on rope 1")
        for i in range(1, 4):
            offsets.append(x[j, i] * 1e6 - S[kernel._XH_Q8UM + i] / 256)
            # the re-anchoring is no seal travel: x_s moved by this sample's step only
            assert abs(S[kernel.XS_Q8UM + i] - xs[i]) < 256, (seed, i)
    offsets = np.array(offsets)
    print(f"stopped pistons after the start: {offsets.mean():+.2f} um mean, "
          f"{np.sqrt(np.mean(offsets ** 2)):.2f} um rms")
    assert abs(offsets.mean()) < 0.5 and np.sqrt(np.mean(offsets ** 2)) < 0.7, offsets


def test_a_drawn_winds_stroke_starts_place_the_stopped_pistons_in_the_nodes_steps():
    """The first 7.5 s of a drawn hoist's wind whose ropes part through it (population
    tuning seed 14, groove creep: tests/vectors/drawn-wind-stroke-end.npz, its stream and
    commissioned config). At a stroke start the stopped ropes' e is the stroke piston's
    lead shared by area plus the lag of e; the node takes the area ratio in Q8, the lead
    and the lag in its floored steps, and x_h keeps that offset (up to ~0.01 um): the float
    reference taking them exactly ended the next stroke one sample before the node did,
    and the one sample of x_h standing or not put them 0.064 % of rated apart (0.085 %
    on a frame later in the wind). The reference now takes them in the node's steps:
    the same strokes at the same samples and 0.005 % apart."""
    import array
    import json
    from pathlib import Path

    vec = np.load(Path(__file__).resolve().parents[1] / "vectors" / "drawn-wind-stroke-end.npz")
    doc = json.loads(str(vec["node_json"]))
    recs = vec["records"]
    # written when `physical` still carried a copy of the node's id and key (now `node` only)
    ph = {k: v for k, v in doc["physical"].items() if k not in ("node_id", "key_hex")}
    ref = []
    comp = reference.compensate(ph, recs, strokes=ref)
    node = Node(config.parse(doc))
    kernel = node_module("kernel")
    mode, events = 0, []

    # the node's stroke starts and ends (as `ropemon study stroke-events` reads them) and tensions
    ten = np.zeros((len(recs), node.n))
    good = np.zeros((len(recs), node.n), bool)
    rec = array.array("H", [0] * recs.shape[1])
    for j, row in enumerate(recs.tolist()):
        rec[:] = array.array("H", row)
        node.sample(rec)
        ten[j] = node.rope(kernel.TENSION_N)
        good[j] = [(node.S[kernel.GOOD] >> i) & 1 for i in range(node.n)]
        if node.S[kernel._SMODE] != mode:
            mode = node.S[kernel._SMODE]
            events.append((j, mode - 1))
    assert len(events) >= 2 and events == [(j, r) for j, r, _ in ref], (events, ref)
    assert (good == comp.good).all()
    err = np.abs(ten - comp.tension_n)[good]
    assert err.max() <= _tolerance_n(doc), err.max() / ph["rated_rope_tension_N"]


def _rest_records(ph: dict, seconds: float, seed: int, noise_pa=5200.0) -> tuple[np.ndarray, np.ndarray]:
    """(records, t) of a loading (4 -> 5 MPa over 4 s, from 3 s) and then a long rest: the
    pistons move only as their oil compresses (x = k p), each pressure channel with 5.2 kPa
    of white noise (a field-trip transmitter; or `noise_pa`, one value or one per rope), as
    the node sees them."""
    fs = int(ph["sample_hz"])
    t = np.arange(0, seconds, 1 / fs)
    p_pa = 4e6 + 1e6 * np.clip((t - 3) / 4, 0, 1)
    recs = _compression_records(ph, p_pa, 3e-10)
    rng = np.random.default_rng(seed)
    n = int(ph["ropes"])
    for i, noise in zip(range(n), np.broadcast_to(noise_pa, (n,))):
        pc = ph["pressure_channels"][i]
        lo, hi = pc["range_Pa"]
        per_pa = (pc["counts_20mA"] - pc["counts_4mA"]) / (hi - lo)
        recs[:, i] = np.round(pc["counts_4mA"] + (p_pa + rng.normal(0, noise, len(t)) - lo) * per_pa)
    return recs, t


def _rest_physical(**changes) -> dict:
    """The example site with a compliance and its observer defaults (COMPLIANCE_DEFAULTS),
    a stiff seal and the pressure noise of _rest_records."""
    ph = example_physical()
    ph["friction"] = dict(ph["friction"], sigma0=1e8, sigma1=1e5)
    ph["piston_speed_max_m_s"] = 0.05
    for key in COMPLIANCE_DEFAULTS:
        ph.pop(key, None)
    ph.update({"hydraulic_compliance_m_per_Pa": [3e-10] * 4, "pressure_noise_Pa": 5200.0, **changes})
    return ph


def test_at_rest_the_pressure_noise_does_not_wear_the_seal_state_down():
    """After a loading the seals hold about 6 kN each. Over the minute of rest that
    follows, the pressure noise alone would make travel through the play and relax them
    (by more than 2.5 kN without the rest hold); with it (docs/model.md, "Rest hold") every
    rope's friction stays within 150 N from 5 s after the loading (the elastic part still
    follows the position noise), in the node as in the reference."""
    doc = make_node_json(_rest_physical())
    ph = doc["physical"]
    fs = int(ph["sample_hz"])
    recs, t = _rest_records(ph, 70, 5)
    held = reference.compensate(ph, recs)
    loose = reference.compensate(dict(ph, rest_sigmas=0.0), recs)
    a, b = int(12 * fs), len(t) - 1
    assert (held.friction_n[a] > 5000).all(), held.friction_n[a]
    drift = np.abs(held.friction_n[a:b] - held.friction_n[a]).max(axis=0)
    assert (drift < 150).all(), drift
    assert (loose.friction_n[a] - loose.friction_n[b] > 2500).all(), (loose.friction_n[a], loose.friction_n[b])
    ten, good, _ = run_node(Node(config.parse(doc)), recs)
    assert good[fs:].all()
    err = np.abs(ten - held.tension_n)[good]
    assert err.max() <= _tolerance_n(doc), err.max()


def test_a_faulted_pressure_loop_sizes_the_play_for_the_median_of_the_others(monkeypatch):
    """With rope 1's pressure loop open, the LuGre position of the other ropes takes the
    median of three channels, 1.23 times noisier than of four: the node widens the play
    to match (nodejson MEDIAN_NOISE), so without the rest hold the noise relaxes their
    seals over 18 s of rest by a quarter less than with the play of four channels; the
    node does as the reference."""
    from ropemon.commission import nodejson

    doc = make_node_json(_rest_physical(rest_sigmas=0.0))
    ph = doc["physical"]
    fs = int(ph["sample_hz"])
    recs, t = _rest_records(ph, 70, 5)
    recs[t >= 10, 0] = 0  # below 3.6 mA
    a, b = int(12 * fs), int(30 * fs)
    per_count = reference.compensate(ph, recs).friction_n
    monkeypatch.setattr(nodejson, "MEDIAN_NOISE", (nodejson.MEDIAN_NOISE[3],) * 4)
    one_play = reference.compensate(ph, recs).friction_n
    monkeypatch.undo()
    relax, relax_one = per_count[a, 1:] - per_count[b, 1:], one_play[a, 1:] - one_play[b, 1:]
    assert (relax < 0.85 * relax_one).all(), (relax, relax_one)
    ten, good, _ = run_node(Node(config.parse(doc)), recs)
    assert not good[t >= 10, 0].any() and good[t >= 1, 1:].all()
    err = np.abs(ten - reference.compensate(ph, recs).tension_n)[good]
    assert err.max() <= _tolerance_n(doc), err.max()


def test_noise_following_sizes_the_plays_for_the_noise_the_transmitters_have_now():
    """The transmitters 20 % noisier or quieter than commissioned (pressure_noise_Pa 5.2
    kPa): the noise following (docs/model.md) measures each channel's level and scales
    the plays and the rest threshold by the ratio, which reaches 1.2 or 0.8 within 3 %
    over a 70 s rest (noise_follow_s 20 s) and stays within 2 % of 1 at the noise as
    commissioned; the node's ratio is the reference's within 2/1024. Without the rest
    hold, the noise relaxes the seals over the rest by nearly as much as at the noise as
    commissioned: less than 0.6 of the difference that fixed plays make."""
    kernel = node_module("kernel")
    relax = {}
    for follow in (20.0, 0.0):
        doc = make_node_json(_rest_physical(rest_sigmas=0.0, noise_follow_s=follow))
        ph = doc["physical"]
        fs = int(ph["sample_hz"])
        assert (doc["node"]["friction"]["noise_ref_q6"] > 0) == (follow > 0)
        for noise in (5200.0, 6240.0, 4160.0):
            recs, t = _rest_records(ph, 70, 5, noise)
            inc = {}
            ref = reference.compensate(ph, recs, increments=inc)
            ratio = inc["noise_ratio"][-1]
            if follow:
                assert ratio == pytest.approx(noise / 5200.0, rel=0.03 if noise != 5200.0 else 0.02), noise
                node = Node(config.parse(doc))
                ten, good, _ = run_node(node, recs)
                assert abs(node.S[kernel.NOISE_Q10] - ratio * 1024) <= 2  # steps of 1/1024
                err = np.abs(ten - ref.tension_n)[good]
                assert err.max() <= _tolerance_n(doc), (noise, err.max())
            else:
                assert (inc["noise_ratio"] == 1.0).all()
            a, b = int(12 * fs), len(t) - 1
            relax[follow, noise] = ref.friction_n[a] - ref.friction_n[b]
    for noise in (6240.0, 4160.0):
        followed = np.abs(relax[20.0, noise] - relax[20.0, 5200.0])
        fixed = np.abs(relax[0.0, noise] - relax[0.0, 5200.0])
        assert (followed < 0.6 * fixed).all(), (noise, followed, fixed)


def test_frames_flag_a_noise_beyond_what_the_node_follows_unchecked():
    """The node flags its frames noise_changed once its noise ratio is beyond 1 +- 25 %
    (layout.NOISE_TOL_Q10, fit-compliance's re-check tolerance with following): with the
    transmitters 50 % noisier, from 10-20 s after the start to the end; never at the
    noise as commissioned, nor 20 % noisier, nor with the following off."""
    from ropemon.station.decoder import StreamDecoder

    def flagged(follow: float, noise: float) -> np.ndarray:
        doc = make_node_json(_rest_physical(noise_follow_s=follow))
        recs, _t = _rest_records(doc["physical"], 40, 5, noise)
        _ten, _good, frames = run_node(Node(config.parse(doc)), recs)
        decoded = StreamDecoder().feed(b"".join(frames))
        assert len(decoded) == len(frames)
        return np.array([bool(f.status & L.ST_NOISE_CHANGED) for f in decoded])

    noisy = flagged(20.0, 7800.0)
    first = int(np.flatnonzero(noisy)[0])  # 15 s: the level low-pass (20 s) passes 1.25 of 1.5
    assert 100 <= first <= 200 and noisy[first:].all(), np.flatnonzero(noisy)[:5]
    for follow, noise in ((20.0, 5200.0), (20.0, 6240.0), (0.0, 7800.0)):
        assert not flagged(follow, noise).any(), (follow, noise)


def test_one_noisier_transmitter_at_commissioning_is_no_noise_change():
    """Commissioned by fit-compliance on a stream where one transmitter is 40 % noisier
    than the other three, the node reads its noise ratio as 1 within 3 % on that same
    stream and flags no frame noise_changed: the fit gives the median channel's noise,
    the level the node follows. (Sized by the noisiest channel instead, the ratio would
    head for 0.72, with its 20 s time constant from 1, and frames would be flagged from
    about 40 s on.)"""
    from ropemon.commission import compliance
    from ropemon.station.decoder import StreamDecoder

    noise = [5200.0, 5200.0, 7280.0, 5200.0]
    base = _rest_physical()
    recs, _t = _rest_records(base, 70, 6, noise)
    fitted = compliance.fit(base, recs).pressure_noise_pa
    assert fitted == pytest.approx(5200.0, rel=0.05)

    def ratio_and_flags(pressure_noise: float) -> tuple[float, np.ndarray]:
        doc = make_node_json(_rest_physical(pressure_noise_Pa=pressure_noise))
        node = Node(config.parse(doc))
        _ten, _good, frames = run_node(node, recs)
        decoded = StreamDecoder().feed(b"".join(frames))
        flags = np.array([bool(f.status & L.ST_NOISE_CHANGED) for f in decoded])
        return node.S[node_module("kernel").NOISE_Q10] / 1024, flags

    ratio, flags = ratio_and_flags(fitted)
    assert ratio == pytest.approx(1.0, abs=0.03) and not flags.any()
    ratio, flags = ratio_and_flags(max(noise))
    assert ratio < 0.74 and flags[600:].all() and not flags[:300].any()


def test_do_no_harm_holds_back_a_friction_the_pistons_travel_contradicts():
    """Do no harm, on a hand-built stream (`slide_stream`, slide following off): as the pressure
    rises 1 MPa, rope 2's piston goes in by 200 um against its compression (25 um/s against
    15 um/s) while the model, which re-anchors that motion without seal travel, moves its seal
    out with the compression: +3.3 kN at 24 s, where the true seal (sigma0 2e7 N/m) went in
    and holds -2.8 kN. The hoist is at rest throughout (no shaft pulses). Without the limit
    the node reads rope 2 about 6 kN off, worse than raw p A (3 kN off); with it the node
    keeps of its friction only what the seal state from the piston's own travel holds (none:
    that one holds inwards), reads no worse than raw, flags rope 2 held back in its frames,
    and the station's band covers the truth."""
    from ropemon.station import uncertainty

    k_m = 3e-10
    ph = example_physical()
    ph["hydraulic_compliance_m_per_Pa"] = [k_m] * 4
    for key in COMPLIANCE_DEFAULTS:
        ph.pop(key, None)
    ph["slide_follow"] = False
    fs = int(ph["sample_hz"])
    recs, x, p_pa = slide_stream(ph, k_m, 41, slide_um_s=25.0)
    truth = _true_friction(ph, x, p_pa)
    end = slice(24 * fs, 26 * fs)   # the last 2 s of the pressure rise: the pistons still parting
    errs, held = {}, {}
    for sigmas in (3.0, 0.0):
        doc = make_node_json(dict(ph, hold_play_sigmas=sigmas))
        assert (doc["node"]["friction"]["hold_play_q8um"] > 0) == (sigmas > 0)
        ref = reference.compensate(doc["physical"], recs)
        ten, good, frames = run_node(Node(config.parse(doc)), recs)
        assert good[fs:].all()
        assert np.abs(ten - ref.tension_n)[good].max() <= _tolerance_n(doc)
        raw = ref.raw_tension_n
        errs[sigmas] = (np.abs(ten - (raw + truth))[end, 1].mean(), np.abs(truth[end, 1]).mean())
        decoded = [protocol.decode_raw(protocol.decode_wire(b[:-1])) for b in frames]
        held[sigmas] = [f.held_back for f in decoded]
        if sigmas > 0:
            band = uncertainty.SealBandTracker(uncertainty.BandParams.from_physical(doc["physical"]))
            for f, j in zip(decoded, range(len(decoded))):
                band.update(f)
                if 24 * 10 <= j < 26 * 10:   # frames of the same 2 s (10 frames a second)
                    r = band.intervals()[1]
                    t_true = np.mean((raw + truth)[j * fs // 10:(j + 1) * fs // 10, 1])
                    assert r.lo <= t_true <= r.hi, (j, r, t_true)
    node_off, raw_err = errs[0.0]
    node_on, _ = errs[3.0]
    assert truth[end, 1].max() < -2000 and raw_err > 2000               # the seal really went in
    assert node_off > raw_err + 2000, errs                              # the harm without the limit
    assert node_on <= raw_err + 200, errs                               # none with it
    assert any(1 in h for h in held[3.0][24 * 10:26 * 10]) and not any(h for h in held[0.0])
    assert all(1 not in h for h in held[3.0][: 6 * 10])                  # before the pistons part: not held


def test_do_no_harm_leaves_a_friction_the_pistons_travel_agrees_with():
    """Do no harm, the other way (`slide_stream` without its slide): every piston moves with its
    compression as the pressure rises 1 MPa at rest, so the model's seal and the seal state from
    the piston's own travel agree but for x_f's noise, which zm's elastic step takes, sigma0 times
    it (a stiff seal: 1e8 N/m, the paper's), and for the play zm's dissipation waits for. Within
    twice sigma0 times the play of zm the channels do not contradict the model: no rope is cut, in
    the reference or the node, and none is flagged held back. Limited to zm alone, the noise cut
    the friction by up to about 0.8 kN here."""
    k_m = 3e-10
    ph = example_physical()
    ph["hydraulic_compliance_m_per_Pa"] = [k_m] * 4
    for key in COMPLIANCE_DEFAULTS:
        ph.pop(key, None)
    ph["slide_follow"] = False
    ph["friction"] = dict(ph["friction"], sigma0=1e8)
    ph["piston_speed_max_m_s"] = 0.05                           # as the paper's site: sigma0 dx_max in range
    fs = int(ph["sample_hz"])
    recs, _x, _p = slide_stream(ph, k_m, 43, slide_um_s=0.0)
    doc = make_node_json(dict(ph, hold_play_sigmas=3.0))
    ref = reference.compensate(doc["physical"], recs)
    plain = reference.compensate(dict(doc["physical"], hold_play_sigmas=0.0), recs)
    moving = slice(7 * fs, 26 * fs)
    assert np.abs(plain.friction_n[moving]).max() > 1000       # the seal carries friction through the rise
    assert ref.held_n.max() == 0.0, ref.held_n.max()
    assert np.array_equal(ref.tension_n, plain.tension_n, equal_nan=True)
    ten, good, frames = run_node(Node(config.parse(doc)), recs)
    assert np.abs(ten - ref.tension_n)[good].max() <= _tolerance_n(doc)
    decoded = [protocol.decode_raw(protocol.decode_wire(b[:-1])) for b in frames]
    assert not any(f.held_back for f in decoded)


def test_a_node_booted_at_rest_reads_no_friction_from_its_first_samples():
    """At rest with the displacement's 20 um rms noise, the position filters start from one noisy
    sample. Without a compliance b then settles to the mean position within a fraction of a second;
    without the warm-up that settling is seal travel, and a stiff seal's state (sigma0 1e8 N/m, as
    on a drawn hoist) goes to kilonewtons: a friction no seal holds, read as a rope deviation of
    10 % and more. With the 0.5 s warm-up (the default) the largest friction of a rope over the
    first 3 s is, in the median over ropes and noise draws, under 800 N (what the noise moves the
    state by at rest) and under half of it without; in the node as in the reference."""
    ph = example_physical()
    ph["friction"] = dict(ph["friction"], sigma0=1e8, sigma1=1e5)
    ph["piston_speed_max_m_s"] = 0.05
    fs = int(ph["sample_hz"])
    p_pa = np.full(3 * fs, 4e6)
    med = {}
    for warm in (None, 0.0):
        doc = make_node_json(ph if warm is None else dict(ph, friction_warmup_s=warm))
        assert doc["node"]["friction"]["warmup_samples"] == (fs // 2 if warm is None else 0)
        dc = doc["physical"]["displacement_channels"][0]
        per_m = (dc["counts_hi"] - dc["counts_lo"]) / (dc["range_m"][1] - dc["range_m"][0])
        f = []
        for seed in range(4):
            recs = _compression_records(doc["physical"], p_pa, 0.0)
            rng = np.random.default_rng(100 + seed)
            x = recs[:, 4:8].astype(float) + rng.normal(0, 2e-5 * per_m, (len(p_pa), 4))
            recs[:, 4:8] = np.round(x).astype(np.uint16)
            ref = reference.compensate(doc["physical"], recs)
            f += list(np.abs(ref.friction_n).max(axis=0))
            if warm is None and seed == 0:
                ten, good, _ = run_node(Node(config.parse(doc)), recs)
                assert good.all()
                assert np.abs(ten - ref.tension_n).max() <= _tolerance_n(doc)
        med[warm] = float(np.median(f))
    assert med[None] < 800 and med[None] < 0.5 * med[0.0], med
    assert med[0.0] > 1200, med  # the failure the warm-up removes
