"""Build the integer `node` section of node.json from the SI `physical` section.

`build_node_section(physical)` computes every fixed-point constant and table
the firmware uses (scales in docs/model.md, "Fixed-point scales") and proves
that no integer the node computes leaves +-2**30 over the declared ranges; a
physical value that would break that raises ValueError naming the field.
The section is read through `ropemon.station.physical.Physical`, which refuses what is not
physical (ranges, types, list lengths); what is checked here is what the node's fixed point
can represent. `make_node_json(physical, node_id=, key=)` adds the node's identity (in the
node section only: the one copy, which the node and the host both read), schema, CRC and
the document's SHA-256 (`physical.document_digest`), and `write_node_json` writes it with
mode 0600, as it holds the key. `example_physical()` is the documented default for the
paper's field hoist, shipped as firmware/node.json with the example identity
(EXAMPLE_NODE_ID, EXAMPLE_KEY, which `ropemon deploy` refuses without --allow-example-key)
(regenerate: `python -m ropemon.commission.nodejson > firmware/node.json`).
"""
from __future__ import annotations

import functools
import json
import math
import sys
from pathlib import Path
from typing import Any

from ropemon.firmware import node_module
from ropemon.station import files
from ropemon.station.physical import (COMPLIANCE_DEFAULTS, DIGEST, NODE_DEFAULTS, Physical, as_physical,
                                      document_digest)
from ropemon.station.protocol import KEY_LEN_MAX, KEY_LEN_MIN

I30 = 1 << 30
SCHEMA = 1
# The identity of the shipped example (firmware/node.json), the default of the lab's and the
# tests' configs. Published with ropemon, as is the demo key of scenarios/paper-site.toml:
# `ropemon deploy` refuses both (PUBLISHED_KEYS) unless told --allow-example-key.
EXAMPLE_NODE_ID = 1
EXAMPLE_KEY = bytes.fromhex("6f1d3c0a9b2e47c58a61f0d2e3b4c5a6")
PUBLISHED_KEYS = {
    EXAMPLE_KEY: "the example key shipped in firmware/node.json",
    bytes.fromhex("00112233445566778899aabbccddeeff"): "the demo key of scenarios/paper-site.toml",
}
GEXP_STEP = 1 / 32          # u step of the exp(-u^2) table
GEXP_POINTS = 129

# Defaults of the optional physical keys (docs/config.md, docs/model.md): one table, in
# ropemon.station.physical, with the ones a compliance changes (COMPLIANCE_DEFAULTS).
DEFAULTS = NODE_DEFAULTS
# rms of the median of N independent channels of unit rms noise (Gaussian; of two: their
# mean): the LuGre position's pressure with a compliance (docs/model.md)
MEDIAN_NOISE = (1.0, 0.7071, 0.6696, 0.5458)

PLAY_STEP_M = 0.01e-6        # resolution of the LuGre play half-width
NOISE_CLIP = 4               # noise following: |second difference| clipped at this many times the level
NOISE_RANGE = 2              # and the level held within 1/this .. this times the commissioned one
PRESSURE_Q_MAX = 1 << 14    # |count difference| <= 65535: a mul below 2**14 keeps d * mul < 2**30


def namur_limits(c4: int, c20: int) -> tuple[int, int]:
    """(lowest good count, highest good count) of a 4-20 mA loop per NAMUR NE43.

    Below 3.6 mA or above 21 mA is a failed signal; counts are linear in current.
    """
    span = c20 - c4
    lo = math.ceil(c4 - span * 0.4 / 16 - 1e-9)
    hi = math.floor(c4 + span * 17 / 16 + 1e-9)
    return max(lo, 0), min(hi, 65535)


def fit_mul_shift(value: float, max_in: float, field: str, mul_max: int = PRESSURE_Q_MAX,
                  shift_max: int = 24) -> tuple[int, int]:
    """(mul, shift) with mul / 2**shift ~ value, |mul| < mul_max and |mul| * max_in < 2**30.

    The largest shift that fits is taken (best precision).
    """
    if not math.isfinite(value):
        raise ValueError(f"{field}: not a finite number")
    best = None
    for sh in range(0, shift_max + 1):
        m = round(value * (1 << sh))
        if abs(m) >= mul_max or abs(m) * max_in >= I30:
            break
        best = (m, sh)
    if best is None:
        raise ValueError(f"{field}: {value!r} too large for a fixed-point multiplier")
    m, sh = best
    if value != 0 and abs(m / (1 << sh) / value - 1) > 1e-3:
        raise ValueError(f"{field}: {value!r} cannot be represented to 0.1 % "
                         f"(best {m}/2**{sh})")
    return best


def _check(field: str, value: float, limit: float = I30) -> None:
    if not -limit < value < limit:
        raise ValueError(f"{field}: the node would compute {value:.0f}, beyond +-{limit:.0f}")


def filtered_noise_m(noise_m: float, alpha: float, alpha_z: float) -> float:
    """rms of white position noise `noise_m` after the two low-passes x_f (alpha), x_s (alpha_z)."""
    # sum of the squared impulse response of the cascade, summed to its 1e-6 tail
    xf = xs = 0.0
    acc = 0.0
    for k in range(int(40 / alpha_z) + 10):
        xf += alpha * ((1.0 if k == 0 else 0.0) - xf)
        xs += alpha_z * (xf - xs)
        acc += xs * xs
    return noise_m * math.sqrt(acc)


def noise_level_per_rms() -> float:
    """The noise following's level per rms of white Gaussian channel noise: the mean of
    |second difference| (rms sqrt(6)) clipped at NOISE_CLIP times that mean, its fixed point."""
    s = math.sqrt(6)
    level = s * math.sqrt(2 / math.pi)
    for _ in range(50):
        c = NOISE_CLIP * level / s  # the clip in rms of the second difference
        level = s * (math.sqrt(2 / math.pi) * (1 - math.exp(-c * c / 2)) + c * math.erfc(c / math.sqrt(2)))
    return level


TRACKER_ITERATIONS = 100000  # Riccati steps at most (it converges in a few thousand)


@functools.lru_cache(maxsize=64)
def tracker_gains(fs: float, bounce_hz: float, damping: float, q_creep: float, q_bounce: float,
                  r: float) -> dict:
    """The pressure tracker as the node holds it (docs/model.md, "Pressure tracker").

    States (c0, c1, b0, b1): the creep c_{k+1} = 2 c_k - c_{k-1} + w1 and the bounce
    b_{k+1} = a1 b_k - a2 b_{k-1} + w2 (a damped oscillator), measured as y = c0 + b0 + n;
    w1, w2 of variance q h**3 (q a spectral density, Pa**2/s**3), n of variance r (Pa**2).
    The node holds the creep as c and its rate v = c(k) - c(k-1): returns a1 and a2 in
    Q14, the steady-state Kalman gains of (c, v, b0, b1) as the node holds them (`k_q14`:
    of c in Q14, of v in Q(14 + v_shift), of b in Q(14 + b_shift); v and b held 2**shift
    finer than c), and `noise_gain`, the rms of the output per rms of white noise at its
    input (of the quantised filter). Refuses a filter the node cannot hold or that does
    not settle."""
    h = 1.0 / fs
    w = 2 * math.pi * bounce_hz
    rho = math.exp(-damping * w * h)
    a1q = round(2 * rho * math.cos(w * h * math.sqrt(max(0.0, 1 - damping * damping))) * 16384)
    a2q = round(rho * rho * 16384)
    if not (0 < a2q < 16384 and 0 < a1q < 32768):
        raise ValueError(f"physical.bounce_hz: {bounce_hz} Hz with damping {damping} at {fs} Hz "
                         "is outside what the node's tracker holds")
    a1, a2 = a1q / 16384, a2q / 16384
    F = ((2.0, -1.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, a1, -a2), (0.0, 0.0, 1.0, 0.0))
    q = (q_creep * h ** 3, 0.0, q_bounce * h ** 3, 0.0)
    P = [[r if i == j else 0.0 for j in range(4)] for i in range(4)]
    K = [0.0] * 4
    for _ in range(TRACKER_ITERATIONS):
        FP = [[sum(F[i][m] * P[m][j] for m in range(4)) for j in range(4)] for i in range(4)]
        Pp = [[sum(FP[i][m] * F[j][m] for m in range(4)) + (q[i] if i == j else 0.0)
               for j in range(4)] for i in range(4)]
        ph = [Pp[i][0] + Pp[i][2] for i in range(4)]  # Pp H^T
        s = ph[0] + ph[2] + r
        Kn = [x / s for x in ph]
        P = [[Pp[i][j] - Kn[i] * ph[j] for j in range(4)] for i in range(4)]
        done = max(abs(x - y) for x, y in zip(Kn, K)) < 1e-13
        K = Kn
        if done:
            break
    else:
        raise ValueError("physical.bounce_hz: the pressure tracker's gains do not converge")
    # the node holds the creep as (c, v), v = c(k) - c(k-1) 2**vsh finer than c, and the
    # bounce 2**bsh finer than c (c itself in kPa/2048): each gain within 2**14 in its scale
    kv_f = K[0] - K[1]
    vsh = 0
    while vsh < 12 and abs(kv_f) * (1 << (15 + vsh)) < 16383.5:
        vsh += 1
    bsh = 5
    while bsh > 0 and max(abs(K[2]), abs(K[3])) * (1 << (14 + bsh)) >= 16383.5:
        bsh -= 1
    kq = [round(K[0] * 16384), round(kv_f * (1 << (14 + vsh))),
          round(K[2] * (1 << (14 + bsh))), round(K[3] * (1 << (14 + bsh)))]
    if max(abs(x) for x in kq) > 16384:
        raise ValueError("physical.creep_q_Pa2_s3: the pressure tracker's gains exceed 1")
    # the quantised filter's response to a unit impulse: its noise gain, and that it settles
    g = (kq[0] / 16384, kq[1] / (1 << (14 + vsh)), kq[2] / (1 << (14 + bsh)), kq[3] / (1 << (14 + bsh)))
    c = v = b0 = b1 = 0.0
    acc = tail = 0.0
    n = int(40 * fs)
    for j in range(n):
        c += v
        b0, b1 = a1 * b0 - a2 * b1, b0
        e = (1.0 if j == 0 else 0.0) - c - b0
        c += g[0] * e
        v += g[1] * e
        b0 += g[2] * e
        b1 += g[3] * e
        o = (c + b0) ** 2
        acc += o
        if j >= n - int(fs):
            tail += o
    if not math.isfinite(acc) or tail > 1e-12 * acc:
        raise ValueError("physical.bounce_hz: the pressure tracker does not settle with these settings")
    return {"a1_q14": a1q, "a2_q14": a2q, "k_q14": kq, "v_shift": vsh, "b_shift": bsh,
            "noise_gain": math.sqrt(acc)}


def pressure_tracker(ph: dict | Physical, fs: float, n: int) -> dict:
    """tracker_gains for `physical` (with the compliance defaults applied): the median of
    all n channels' noise, with the node's kPa/16 rounding, is the measurement noise."""
    p = as_physical(ph)
    return tracker_gains(fs, p.setting("bounce_hz"), p.setting("bounce_filter_damping"),
                         p.setting("creep_q_Pa2_s3"), p.setting("bounce_q_Pa2_s3"),
                         (MEDIAN_NOISE[n - 1] * pressure_noise_pa(p)) ** 2)


def pressure_scale(ch, field: str = "physical.pressure_channels[]") -> tuple[int, int, int]:
    """(kpa_at_4ma, kpa_mul, kpa_shift) of a pressure channel as the node reads it:
    kPa/16 = kpa_at_4ma * 16 + ((counts - counts_4mA) * kpa_mul) >> (kpa_shift - 4)."""
    lo, hi = ch.range_Pa
    pa_per_count = (hi - lo) / (ch.counts_20mA - ch.counts_4mA)
    km, ks = fit_mul_shift(pa_per_count / 1000, 65535, field + ".range_Pa")
    if ks < 4:  # the node also reads kPa/16 with this mul
        raise ValueError(f"{field}.range_Pa: {pa_per_count / 1000:g} kPa per count, the node "
                         "reads at most 1024")
    return round(lo / 1000), km, ks


def pressure_noise_pa(ph: dict | Physical) -> float:
    """rms noise of one pressure channel as the node reads it (in kPa/16 steps)."""
    return math.hypot(as_physical(ph).setting("pressure_noise_Pa"), 1e3 / 16 / math.sqrt(12))


PRESSURE_STEP_NOISE_SIGMAS = 6  # the step limit's margin for the noise of two readings' difference


def pressure_step_max_pa(ph: dict | Physical) -> list[float]:
    """Per rope, the largest plausible change of its sensor pressure from one sample to the
    next (Pa; 0: not checked): `pressure_step_max_Pa` where written, else the largest legal
    rate of tension change over the sample rate plus the noise (docs/model.md, "Channels"):
    the rope's tension swinging by the rated tension at the bounce, 2 pi bounce_hz T_r / A_i,
    plus PRESSURE_STEP_NOISE_SIGMAS times the rms of two readings' difference."""
    p = as_physical(ph)
    if p.pressure_step_max_Pa is not None:
        return [p.pressure_step_max_Pa] * p.ropes
    rate = [2 * math.pi * p.setting("bounce_hz") * p.rated_rope_tension_N / a for a in p.cylinder_area_m2]
    noise = PRESSURE_STEP_NOISE_SIGMAS * math.sqrt(2) * pressure_noise_pa(p)
    return [r / p.sample_hz + noise for r in rate]


def pressure_step_counts(ph: dict | Physical) -> list[int]:
    """`pressure_step_max_pa` per rope in its channel's counts, as the node compares them
    (rounded up; at most 65535; 0: not checked)."""
    p = as_physical(ph)
    out = []
    for lim, ch in zip(pressure_step_max_pa(p), p.pressure_channels):
        pa_per_count = abs(ch.range_Pa[1] - ch.range_Pa[0]) / (ch.counts_20mA - ch.counts_4mA)
        out.append(0 if lim == 0 else min(65535, max(1, math.ceil(lim / pa_per_count - 1e-9))))
    return out


def physical_params(ph: dict | Physical) -> dict:
    """The SI quantities both the builder and the float reference derive from `physical`
    (a dict is checked by Physical.from_dict: ValueError naming the field)."""
    p = as_physical(ph)
    n = p.ropes
    fs = float(p.sample_hz)
    k = list(p.compliance)
    fc_hz = p.velocity_cutoff_hz
    fz_hz = p.setting("friction_cutoff_hz")
    # low-pass gains as the node holds them (Q14): a 0.03 Hz gain is 15.4/16384, and the
    # reference must follow the node's 15, not the exact value, to agree within 0.05 %
    alpha, alpha_z = (max(1, round((1 - math.exp(-2 * math.pi * f / fs)) * 16384)) / 16384
                      for f in (fc_hz, fz_hz))
    q_m = max(c.m_per_count for c in p.displacement_channels)
    noise_m = p.setting("displacement_noise_m")
    # rms noise of the LuGre position that makes false travel: without compliance, the
    # displacement's through both low-passes; with it, k times the noise of the median of
    # the ropes' pressure channels, each with the node's kPa/16 steps) through the pressure
    # tracker (b's noise then wanders too slowly to count). Per count m = 1..n of healthy
    # pressure channels: the median of fewer is noisier, so a faulted loop widens the play
    tracker = None
    if any(k):
        tracker = pressure_tracker(p, fs, n)
        p_noise = pressure_noise_pa(p) * tracker["noise_gain"]
        sigmas = [max(k) * MEDIAN_NOISE[m - 1] * p_noise for m in range(1, n + 1)]
    else:
        sigmas = [filtered_noise_m(math.hypot(noise_m, abs(q_m) / math.sqrt(12)), alpha, alpha_z)] * n
    # in steps of PLAY_STEP_M: channels that differ by a few counts per metre share a play
    def in_steps(key: str) -> list[float]:
        m = p.setting(key)
        return [PLAY_STEP_M * round(m * s / PLAY_STEP_M) for s in sigmas]
    plays = in_steps("friction_play_sigmas")
    # the rest hold: only with a compliance (without one b is the position low-pass itself)
    rest = in_steps("rest_sigmas") if any(k) else [0.0] * n
    rest_plays = in_steps("rest_play_sigmas")
    if any(rest) and min(rest_plays) < max(plays):
        raise ValueError("physical.rest_play_sigmas: must be at least friction_play_sigmas")
    # noise following: the level the plays are sized for (Pa) and the low-pass's shift
    follow_s = p.setting("noise_follow_s")
    noise_ref, noise_shift = 0.0, 0
    if any(k) and follow_s > 0:
        noise_ref = pressure_noise_pa(p) * noise_level_per_rms()
        noise_shift = min(16, max(1, round(math.log2(follow_s * fs))))
    alpha_l, alpha_a = (max(1, round((1 - math.exp(-2 * math.pi * p.setting(key) / fs)) * 16384))
                        / 16384 for key in ("rest_slow_cutoff_hz", "rest_cutoff_hz"))
    fe_hz = p.setting("stroke_cutoff_hz")
    alpha_e = min(4096, max(1, round((1 - math.exp(-2 * math.pi * fe_hz / fs)) * 16384))) / 16384
    # each cylinder's area over the mean (Q8, as the node holds it); build_node_section
    # refuses weights beyond 0.5 .. 1.5
    areas = p.cylinder_area_m2
    area_w = [round(256 * a * n / sum(areas)) / 256 for a in areas]
    # a stroke shows in the low-pass of x_f - x_h beyond stroke_sigmas times its noise:
    # the displacement's through x_f and that low-pass; only with a compliance and 2+
    # ropes (stroke_sigmas 0: not tracked)
    stroke_m = 0.0
    sigmas = p.setting("stroke_sigmas")
    # slide following: lo and the span hi - lo in e's noise, in the node's um/256 (span >= 1)
    slide_on = p.setting("slide_follow")
    lo_s = p.setting("slide_follow_lo_sigmas")
    hi_s = p.setting("slide_follow_hi_sigmas")
    slide_lo_m = slide_span_m = 0.0
    if any(k) and n > 1 and sigmas > 0:
        e_noise = filtered_noise_m(math.hypot(noise_m, abs(q_m) / math.sqrt(12)), alpha, alpha_e)
        stroke_m = max(1, round(sigmas * e_noise * 256e6)) / 256e6
        if slide_on and hi_s > lo_s:
            slide_lo_m = round(lo_s * e_noise * 256e6) / 256e6
            slide_span_m = max(1, round((hi_s - lo_s) * e_noise * 256e6)) / 256e6
    # do no harm: the play of the measured seal state, in x_f's rms noise (the displacement's
    # through the velocity low-pass), in the node's um/256
    xf_noise = math.hypot(noise_m, abs(q_m) / math.sqrt(12)) * math.sqrt(alpha / (2 - alpha))
    hold_play_m = round(p.setting("hold_play_sigmas") * xf_noise * 256e6) / 256e6
    return {
        "ropes": n,
        "alpha": alpha,
        "hold_play_m": hold_play_m,  # do no harm: the measured seal state's play (0: off)
        "alpha_z": alpha_z,
        "tracker": tracker,          # the pressure tracker (None without a compliance)
        "alpha_e": alpha_e,
        "area_w": area_w,
        "stroke_m": stroke_m,
        "slide_lo_m": slide_lo_m,      # slide following: |e| from which the take-over is travel
        "slide_span_m": slide_span_m,  # and over which it becomes all travel (0: off)
        # um/65536 per sample, as the node compares it (at most 2**29)
        "stroke_vmin": min(round(p.setting("stroke_min_speed_m_s") / fs * 1e6 * 65536), 1 << 29) / 65536e6,
        "stroke_settle": round(p.setting("stroke_settle_s") * fs),
        "compliance": k,
        "warmup": round(p.setting("friction_warmup_s") * fs),
        # the play half-width with every pressure channel healthy, and per count of them
        "play_m": plays[-1],
        "plays_m": plays,
        "rest_m": rest,              # activity threshold per count (all 0: no rest hold)
        "rest_plays_m": rest_plays,  # the play while quiet
        "noise_ref_pa": noise_ref,   # noise following: the level the plays are sized for (0: fixed)
        "noise_shift": noise_shift,  # its low-pass gain is 2**-noise_shift
        "alpha_l": alpha_l,
        "alpha_a": alpha_a,
        "v_max": p.setting("piston_speed_max_m_s"),
        "p_max_pa": p.friction_p_max_Pa,
        # an implausible pressure step: the limit per rope in counts (0: not checked), and
        # the samples of plausible steps before the channel is good again
        "pressure_step_counts": pressure_step_counts(p),
        "pressure_step_recover": min(65535, max(1, round(p.setting("pressure_step_recover_s") * fs))),
    }


def _tracker_fields(tr: dict | None) -> dict:
    """The node's `friction.tracker_*` keys (all 0 without a compliance: no tracker runs)."""
    if tr is None:
        return {"tracker_a1_q14": 0, "tracker_a2_q14": 0, "tracker_k_q14": [0, 0, 0, 0],
                "tracker_v_shift": 0, "tracker_b_shift": 0}
    return {"tracker_a1_q14": tr["a1_q14"], "tracker_a2_q14": tr["a2_q14"], "tracker_k_q14": tr["k_q14"],
            "tracker_v_shift": tr["v_shift"], "tracker_b_shift": tr["b_shift"]}


def sigma0_max(ph: dict | Physical) -> float:
    """The stiffest pre-sliding sigma0 (N/m) the node represents for this config.

    The bristle increment sigma0 * dx of the largest believable per-sample step
    (piston_speed_max_m_s / sample_hz) must stay below 2**19 * 16 N (a 1 % margin
    covers the rounding of the multiplier). A stiffer seal is, at the displacement
    channel's resolution, a seal with no measurable pre-sliding at all.
    """
    p = as_physical(ph)
    dx_max_q8um = round(p.setting("piston_speed_max_m_s") / p.sample_hz * 256e6)
    return 0.99 * (1 << 19) * 16e6 / dx_max_q8um


STROKE_OFF_Q8UM = 1 << 25  # beyond any position a displacement channel reads (checked above)
STROKE_LIMIT_Q8UM = 1 << 29  # the node's range of the stroke and travel keys


def stroke_limits(ph: dict | Physical) -> dict[str, list[int]]:
    """The node's stroke keys, per rope, in its um/256 from mid-stroke (x > 0: pulled out):
    `stroke_lo_q8um` / `stroke_hi_q8um`, where the margin band starts at the retracted /
    extended end (-stroke/2 + margin, stroke/2 - margin), and `travel_lo_q8um` /
    `travel_hi_q8um`, beyond which a reading is the channel's fault (-+(stroke/2 + travel
    tolerance)). Without `physical.stroke_m` all four are +-STROKE_OFF_Q8UM: no position is
    ever in a band or beyond the travel (nothing checked)."""
    p = as_physical(ph)
    if p.stroke_m is None:
        off = [STROKE_OFF_Q8UM] * p.ropes
        return {"stroke_lo_q8um": [-x for x in off], "stroke_hi_q8um": off,
                "travel_lo_q8um": [-x for x in off], "travel_hi_q8um": off}
    margin, tol = p.stroke_margin, p.travel_tolerance
    out = {"stroke_lo_q8um": [round((-s / 2 + margin) * 256e6) for s in p.stroke_m],
           "stroke_hi_q8um": [round((s / 2 - margin) * 256e6) for s in p.stroke_m],
           "travel_lo_q8um": [-round((s / 2 + tol) * 256e6) for s in p.stroke_m],
           "travel_hi_q8um": [round((s / 2 + tol) * 256e6) for s in p.stroke_m]}
    for key, values in out.items():
        for i, v in enumerate(values):
            _check(f"physical.stroke_m[{i}] ({key}, um/256)", v, STROKE_LIMIT_Q8UM + 1)
    return out


TENSION_MAX_N = 1 << 19  # N: config.py TENSION_MAX_N


def _header_section(p: Physical, pp: dict, node_id: int, key: bytes) -> dict[str, Any]:
    """The node section's head: the node's identity (id, key), the rope count and rates, the
    alarms' figures (rated tension, imbalance, battery low) and the battery's scale."""
    if type(node_id) is not int or not 0 <= node_id <= 255:
        raise ValueError(f"node_id: must be an integer 0..255, got {node_id!r}")
    key = bytes(key)
    if not KEY_LEN_MIN <= len(key) <= KEY_LEN_MAX:
        raise ValueError(f"key: must be {KEY_LEN_MIN}..{KEY_LEN_MAX} bytes, got {len(key)}")
    for i, w in enumerate(pp["area_w"]):
        if not 0.5 <= w <= 1.5:
            raise ValueError(f"physical.cylinder_area_m2[{i}]: {w:.2f} times the ropes' mean area; the node "
                             "shares the oil's motion among cylinders within 0.5 .. 1.5 of it")
    p_kpa_max = math.ceil(pp["p_max_pa"] / 1000)
    _check("physical.pressure_channels", p_kpa_max, 100000)
    nd: dict[str, Any] = {
        "node_id": node_id,
        "key": list(key),
        "ropes": p.ropes,
        "sample_hz": p.sample_hz,
        "frame_hz": p.frame_hz,
        "rated_rope_tension_n": round(p.rated_rope_tension_N),
        "imbalance_permille": round(p.imbalance_frac * 1000),
        "battery_low_mv": round(p.battery_low_V * 1000),
        "p_kpa_max": p_kpa_max,
    }
    bm, bs = fit_mul_shift(p.battery_V_per_count * 1000, 65535,
                           "physical.battery_V_per_count")
    nd["battery_mv_mul"], nd["battery_mv_shift"] = bm, bs
    return nd


def _pressure_section(p: Physical, pp: dict) -> tuple[list[dict], float]:
    """`pressure`: each pressure channel's NAMUR fault limits, kPa and tension scales and step
    limit; and the largest raw tension (N) the channels read within their fault limits."""
    areas = p.cylinder_area_m2
    pressure = []
    raw_t_max = 0.0
    for i, ch in enumerate(p.pressure_channels):
        f = f"physical.pressure_channels[{i}]"
        c4, c20 = ch.counts_4mA, ch.counts_20mA
        lo, hi = ch.range_Pa
        flo, fhi = namur_limits(c4, c20)
        pa_per_count = (hi - lo) / (c20 - c4)
        _, km, ks = pressure_scale(ch, f)
        tm, ts = fit_mul_shift(pa_per_count * areas[i], 65535, f + ".range_Pa*cylinder_area_m2")
        for c in (flo, fhi):
            t = lo * areas[i] + (c - c4) * pa_per_count * areas[i]
            _check(f"physical.cylinder_area_m2[{i}] x {f[9:]}.range_Pa (tension at the NAMUR "
                   "limits)", t, TENSION_MAX_N)
            raw_t_max = max(raw_t_max, abs(t))
        pressure.append({"counts_4ma": c4, "fault_lo_counts": flo, "fault_hi_counts": fhi,
                         "kpa_at_4ma": round(lo / 1000), "kpa_mul": km, "kpa_shift": ks,
                         "tension_n_at_4ma": round(lo * areas[i]), "tension_n_mul": tm,
                         "tension_n_shift": ts, "step_max_counts": pp["pressure_step_counts"][i]})
    return pressure, raw_t_max


def _displacement_section(p: Physical) -> list[dict]:
    """`displacement`: each displacement channel's fault limits and its scale (um/256)."""
    displacement = []
    for i, ch in enumerate(p.displacement_channels):
        f = f"physical.displacement_channels[{i}]"
        clo, chi = ch.counts_lo, ch.counts_hi
        lo, hi = ch.range_m
        flo, fhi = namur_limits(clo, chi)
        q8_per_count = (hi - lo) / (chi - clo) * 256e6
        dm, ds = fit_mul_shift(q8_per_count, 65535, f + ".range_m")
        for c in (flo, fhi):
            _check(f + " (position at the fault limits, um/256)",
                   lo * 256e6 + (c - clo) * q8_per_count, 1 << 25)
        displacement.append({"counts_lo": clo, "fault_lo_counts": flo, "fault_hi_counts": fhi,
                             "q8um_at_lo": round(lo * 256e6), "q8um_mul": dm, "q8um_shift": ds})
    return displacement


def _velocity_section(pp: dict, fs: int) -> dict[str, int]:
    """`velocity`: the piston velocity's low-pass gain and the largest believable step per sample."""
    dx_max = round(pp["v_max"] / fs * 256e6)
    _check("physical.piston_speed_max_m_s (dx_max * sample_hz)", dx_max * fs, 1 << 28)
    return {"alpha_q14": max(1, round(pp["alpha"] * 16384)), "dx_max_q8um": dx_max}


def _stroke_fields(pp: dict) -> dict[str, int]:
    """friction's stroke threshold, slide following's lo and span and the do-no-harm play, in
    the node's um/256."""
    stroke_q8um = round(pp["stroke_m"] * 256e6)
    _check("physical.stroke_sigmas (stroke threshold, um/256)", stroke_q8um, (1 << 15) + 1)
    slide_lo_q8um = round(pp["slide_lo_m"] * 256e6)
    slide_span_q8um = round(pp["slide_span_m"] * 256e6)
    _check("physical.slide_follow_lo_sigmas (slide following's lo, um/256)", slide_lo_q8um, (1 << 24) + 1)
    _check("physical.slide_follow_hi_sigmas (slide following's span hi - lo, um/256)",
           slide_span_q8um, (1 << 20) + 1)
    hold_play_q8um = round(pp["hold_play_m"] * 256e6)
    _check("physical.hold_play_sigmas (the measured seal state's play, um/256)", hold_play_q8um, (1 << 24) + 1)
    return {"stroke_q8um": stroke_q8um, "slide_lo_q8um": slide_lo_q8um, "slide_span_q8um": slide_span_q8um,
            "hold_play_q8um": hold_play_q8um}


def _play_fields(pp: dict) -> dict[str, Any]:
    """friction's plays (um/256), the rest hold's activity threshold (um/65536) and noise
    following's level (kPa/16, Q6), per count of healthy pressure channels."""
    play_q8um = [round(w * 256e6) for w in pp["plays_m"]]
    rest_play_q8um = [round(w * 256e6) for w in pp["rest_plays_m"]]
    rest_q16um = [round(w * 65536e6) for w in pp["rest_m"]]  # the activity is held in um/65536
    _check("physical.friction_play_sigmas (play half-width, um/256)", max(play_q8um), 1 << 24)
    _check("physical.rest_play_sigmas (play half-width, um/256)", max(rest_play_q8um), (1 << 20) + 1)
    _check("physical.rest_sigmas (activity threshold, um/65536)", max(rest_q16um), (1 << 21) + 1)
    # noise following: the level in kPa/16, Q6; it scales the plays and the threshold up to
    # NOISE_RANGE times, which the node's products and the rest hold's quiet stay within
    noise_ref_q6 = round(pp["noise_ref_pa"] / 62.5 * 64)  # 0 without following
    if pp["noise_shift"]:
        _check("physical.pressure_noise_Pa (noise following's level, kPa/16 Q6)", noise_ref_q6, (1 << 18) + 1)
        _check("physical.rest_sigmas (activity threshold with noise following, um/65536)",
               max(rest_q16um), 1 << 20)
    return {"play_q8um": play_q8um, "rest_play_q8um": rest_play_q8um, "rest_q16um": rest_q16um,
            "noise_ref_q6": noise_ref_q6}


def _seal_fields(p: Physical, dx_max: int, v_max_um_s: int, p_kpa_max: int) -> tuple[dict, dict, float]:
    """The LuGre seal's keys of `friction`: (sigma0 and sigma1's multipliers, the pressure lines
    Fs, Fc, vs and sigma2 with sigma2's shift, the largest friction force in N)."""
    fs = p.sample_hz
    fr = p.friction

    def flin(key: str) -> tuple[float, float]:
        line = getattr(fr, key)
        return line.intercept, line.slope

    sigma0 = fr.sigma0
    sigma1 = fr.sigma1
    s0m, s0s = fit_mul_shift(sigma0 / 16e6, dx_max, "physical.friction.sigma0", mul_max=1 << 11)
    _check("physical.friction.sigma0 (sigma0 * dx_max, N/16)", (dx_max * s0m) >> s0s, 1 << 19)
    c1 = sigma1 / (sigma0 / fs)
    c1m, c1s = fit_mul_shift(c1, 1 << 10, "physical.friction.sigma1 (sigma1 fs / sigma0)",
                             mul_max=1 << 19)
    if c1s < 10:
        raise ValueError(f"physical.friction.sigma1: sigma1 fs / sigma0 = {c1:g} too large (max 512)")
    lin = {}
    for key, node_key, scale, lo_lim, hi_lim in (("Fs", "fs_n", 1.0, 64, 32767),
                                                 ("Fc", "fc_n", 1.0, 64, 32767),
                                                 ("vs", "vs_um_s", 1e6, 10, 1 << 20)):
        a, b = flin(key)
        for p_mpa in (0.0, p_kpa_max / 1000):
            val = (a + b * p_mpa) * scale
            if not lo_lim <= val <= hi_lim:
                raise ValueError(f"physical.friction.{key}: {val / scale:g} at {p_mpa:g} MPa "
                                 f"out of range {lo_lim / scale:g}..{hi_lim / scale:g}")
        m, s = fit_mul_shift(b * scale / 1000, p_kpa_max, f"physical.friction.{key}.slope",
                             mul_max=1 << 15) if b else (0, 0)
        lin[node_key] = {"at_0": round(a * scale), "slope_mul": m, "slope_shift": s}
        if node_key == "fc_n":
            fs0, fs1 = flin("Fs")
            for p_mpa in (0.0, p_kpa_max / 1000):
                if a + b * p_mpa > fs0 + fs1 * p_mpa:
                    raise ValueError(f"physical.friction.Fc: above Fs at {p_mpa:g} MPa")
    a2, b2 = flin("sigma2")
    s2max = max(a2 + b2 * p for p in (0.0, p_kpa_max / 1000)) * 16e-6  # N/16 per um/s
    if min(a2 + b2 * p for p in (0.0, p_kpa_max / 1000)) < 0:
        raise ValueError("physical.friction.sigma2: negative within the pressure range")
    s2sh = 0
    while s2sh < 24 and s2max * (1 << (s2sh + 1)) < (1 << 18) - 1:
        s2sh += 1
    if s2sh < 9:
        raise ValueError("physical.friction.sigma2: too large for the node's sigma2 scale")
    q = 16e-6 * (1 << s2sh)
    m2, sh2 = fit_mul_shift(b2 * q / 1000, p_kpa_max, "physical.friction.sigma2.slope",
                            mul_max=1 << 15) if b2 else (0, 0)
    lin["sigma2_q"] = {"at_0": round(a2 * q), "slope_mul": m2, "slope_shift": sh2}
    _check("physical.friction.sigma2 (sigma2 * v_max, N/16)", s2max * v_max_um_s, 1 << 19)
    fs_max = max(flin("Fs")[0] + flin("Fs")[1] * p_mpa for p_mpa in (0.0, p_kpa_max / 1000))
    f_max = fs_max * (1 + c1 * 2) + s2max / 16 * v_max_um_s  # |zf| <= Fs, damping, viscous
    sigmas = {"sigma0_mul": s0m, "sigma0_shift": s0s, "c1_mul": c1m, "c1_shift": c1s}
    return sigmas, {**lin, "sigma2_shift": s2sh}, f_max


def _gexp_table() -> list[int]:
    """friction's `gexp_q14`: exp(-u**2) in Q14 at u = 0, GEXP_STEP, ..., its last point 0."""
    gexp = [round(math.exp(-(k * GEXP_STEP) ** 2) * 16384) for k in range(GEXP_POINTS)]
    gexp[-1] = 0
    return gexp


def _compliance_fields(pp: dict) -> dict[str, Any]:
    """friction's hydraulic compliance per rope in (um/256 per kPa) * 2**shift, the largest
    shift that keeps every one below 2**17."""
    k_u = [k * 1e3 * 256e6 for k in pp["compliance"]]
    ksh = 30
    while ksh > 5 and max(k_u) * (1 << ksh) >= (1 << 17) - 1:
        ksh -= 1
    kq = [round(k * (1 << ksh)) for k in k_u]
    for i, q in enumerate(kq):
        if q >= 1 << 17 or (q * 3125) >> (ksh - 5) >= 1 << 25:
            raise ValueError(f"physical.hydraulic_compliance_m_per_Pa[{i}]: too large for the node "
                             "(k times 100 MPa must stay within 0.13 m)")
    return {"compliance_q": kq, "compliance_shift": ksh}


def _friction_section(p: Physical, pp: dict, dx_max: int, v_max_um_s: int,
                      p_kpa_max: int) -> tuple[dict[str, Any], float]:
    """`friction`: the seal (LuGre), its plays and rest hold, noise following, the pressure
    tracker, the compliance, the stroke and slide following; and the largest friction force (N)."""
    stroke = _stroke_fields(pp)
    plays = _play_fields(pp)
    sigmas, lines, f_max = _seal_fields(p, dx_max, v_max_um_s, p_kpa_max)
    gexp = _gexp_table()
    compliance = _compliance_fields(pp)
    section = {**sigmas,
               "alpha_z_q14": max(1, round(pp["alpha_z"] * 16384)), "play_q8um": plays["play_q8um"],
               "rest_play_q8um": plays["rest_play_q8um"], "rest_q16um": plays["rest_q16um"],
               "noise_ref_q6": plays["noise_ref_q6"], "noise_shift": pp["noise_shift"],
               "alpha_l_q14": round(pp["alpha_l"] * 16384), "alpha_a_q14": round(pp["alpha_a"] * 16384),
               **_tracker_fields(pp["tracker"]), **compliance,
               "warmup_samples": min(pp["warmup"], 65535),
               "alpha_e_q14": round(pp["alpha_e"] * 16384), "area_q8": [round(a * 256) for a in pp["area_w"]],
               "stroke_q8um": stroke["stroke_q8um"],
               "stroke_vmin_q16": round(pp["stroke_vmin"] * 65536e6),
               "stroke_settle": min(pp["stroke_settle"], 65535),
               "slide_lo_q8um": stroke["slide_lo_q8um"], "slide_span_q8um": stroke["slide_span_q8um"],
               "hold_play_q8um": stroke["hold_play_q8um"],
               **lines, "gexp_q14": gexp}
    return section, f_max


def _loss_section(p: Physical) -> tuple[dict[str, Any], float]:
    """`loss`: the pipe-loss table per rope (piston speeds in um/s, forces in N per temperature
    row); and the largest loss force (N)."""
    areas = p.cylinder_area_m2
    temps, flows, dps = p.loss.temps_C, p.loss.flow_m3_s, p.loss.dp_Pa
    v_rows, f_rows = [], []
    loss_max = 0.0
    for i in range(p.ropes):
        v_row = [round(q / areas[i] * 1e6) for q in flows]
        if any(b <= a for a, b in zip(v_row, v_row[1:])) or v_row[-1] >= 1 << 19:
            raise ValueError(f"physical.loss.flow_m3_s: piston speeds of rope {i} not "
                             "distinct in um/s or beyond 0.5 m/s")
        v_rows.append(v_row)
        rows = []
        for t, row in enumerate(dps[i]):
            fr_row = [round(dp * areas[i]) for dp in row]
            if fr_row[0] != 0:
                raise ValueError(f"physical.loss.dp_Pa[{i}][{t}][0]: loss at zero flow must be 0")
            for x in fr_row:
                _check(f"physical.loss.dp_Pa[{i}][{t}] (force)", x, 1 << 16)
                loss_max = max(loss_max, abs(x))
            rows.append(fr_row)
        f_rows.append(rows)
    return {"temps_cc": [round(t * 100) for t in temps], "v_um_s": v_rows, "force_n": f_rows}, loss_max


def _temperature_section(p: Physical) -> dict[str, int]:
    """`temperature`: the oil temperature input's scale and fault limits (all 0 and `fitted` 0
    when not fitted) and the temperature assumed without it."""
    temp = p.temperature
    assumed = round(p.oil_temp_assumed_C * 100)
    if temp is None:
        return {"fitted": 0, "counts_at_0c": 0, "cc_mul": 0, "cc_shift": 0,
                "fault_lo_counts": 0, "fault_hi_counts": 0, "assumed_cc": assumed}
    c0, cpc = temp.counts_at_0C, temp.counts_per_C
    tm_, ts_ = fit_mul_shift(100 / cpc, 65535, "physical.temperature.counts_per_C")
    ends = sorted((c0 - 40 * cpc, c0 + 125 * cpc))  # a reading outside -40..125 C is a fault
    return {"fitted": 1, "counts_at_0c": round(c0), "cc_mul": tm_,
            "cc_shift": ts_,
            "fault_lo_counts": max(0, math.ceil(ends[0])),
            "fault_hi_counts": min(65534, math.floor(ends[1])),
            "assumed_cc": assumed}


def _shaft_section(p: Physical) -> dict[str, Any]:
    """`shaft`: the speed encoder's scale, the most pulses per sample, the Hall marks, and the
    snap distance and start depth (mm)."""
    fs = p.sample_hz
    frame_hz = p.frame_hz
    mpp = p.speed_m_per_pulse
    mmpp_q16 = round(mpp * 1000 * 65536)
    max_pulses = math.ceil(p.setting("hoist_speed_max_m_s") / mpp / fs) + 1
    _check("physical.speed_m_per_pulse (pulses per sample * mm per pulse, Q16)",
           max_pulses * mmpp_q16, 1 << 28)
    _check("physical.speed_m_per_pulse (travel per frame window, Q16)",
           max_pulses * mmpp_q16 * (fs // frame_hz), 1 << 29)
    marks_mm = [round(m * 1000) for m in p.hall_marks_m]
    if any(b <= a for a, b in zip(marks_mm, marks_mm[1:])):
        raise ValueError("physical.hall_marks_m: must ascend in mm (the node's resolution)")
    return {"mm_per_pulse_q16": mmpp_q16, "max_pulses_per_sample": max_pulses,
            "marks_mm": marks_mm, "snap_mm": round(p.setting("hall_snap_m") * 1000),
            "start_depth_mm": round(p.setting("start_depth_m") * 1000)}


def build_node_section(ph: dict | Physical, *, node_id: int = EXAMPLE_NODE_ID, key: bytes = EXAMPLE_KEY) -> dict:
    """The integer node section for physical section `ph` and the node's id and key (raises
    ValueError naming the field): one function per section, checked in this order."""
    p = as_physical(ph)
    pp = physical_params(p)
    fs = p.sample_hz
    nd = _header_section(p, pp, node_id, key)
    nd["pressure"], raw_t_max = _pressure_section(p, pp)
    nd["step_recover"] = pp["pressure_step_recover"]
    nd["displacement"] = _displacement_section(p)
    nd.update(stroke_limits(p))
    nd["velocity"] = _velocity_section(pp, fs)
    dx_max = nd["velocity"]["dx_max_q8um"]
    v_max_um_s = (dx_max * fs + 128) >> 8
    nd["friction"], f_max = _friction_section(p, pp, dx_max, v_max_um_s, nd["p_kpa_max"])
    nd["loss"], loss_max = _loss_section(p)

    t_max = raw_t_max + loss_max + f_max
    _check("physical (largest tension: raw + loss + friction)", t_max, TENSION_MAX_N)
    _check("physical.frame_hz (tension sums over a window)", t_max * (fs // p.frame_hz), I30)

    nd["temperature"] = _temperature_section(p)
    nd["shaft"] = _shaft_section(p)

    # Last line of defence: the node's own validator must accept what we built.
    cfg_mod = node_module("config")
    try:
        cfg_mod.parse_node(nd)
    except cfg_mod.ConfigError as e:
        raise ValueError(f"built {e.field}: {e.reason}") from None
    return nd


def make_node_json(physical: dict | Physical, *, node_id: int = EXAMPLE_NODE_ID,
                   key: bytes = EXAMPLE_KEY) -> dict:
    """A complete node.json document: schema, physical, node (with `node_id` and `key`), crc
    (the node's check of `node`) and sha256 (the host's check of everything: `seal`). The
    example identity is the default: `ropemon config` gives the site's."""
    nd = build_node_section(physical, node_id=node_id, key=key)
    if isinstance(physical, Physical):
        physical = physical.to_dict()
    cfg_mod = node_module("config")
    crc16 = node_module("crc16").crc16
    return seal({"schema": SCHEMA, "physical": physical, "node": nd,
                 "crc": crc16(cfg_mod.canonical(nd))})


def seal(doc: dict) -> dict:
    """`doc` with its `sha256` (re)computed over the rest (`physical.document_digest`): what
    `load_node_json` checks before it uses anything in the file."""
    doc[DIGEST] = document_digest(doc)
    return doc


def write_node_json(path: Path | str, doc: dict) -> Path:
    """Write node.json `doc` to `path`, readable by its owner only (it holds the node's key;
    `files.write_private`)."""
    return files.write_private(path, (json.dumps(doc, indent=1) + "\n").encode())


def node_part(doc: dict) -> dict:
    """What of a node.json the node reads (schema, node, crc): `ropemon deploy` copies only
    this. The `physical` section is the host's (the reference, the tools); on the node
    it would only be parsed at boot, taking as much heap again as the node section."""
    return {key: doc[key] for key in ("schema", "node", "crc") if key in doc}


EXAMPLE_TEMPS_C = (0.0, 20.0, 40.0)
EXAMPLE_FLOWS_M3_S = (0.0, 5e-5, 1e-4, 2e-4, 4e-4, 8e-4, 1.2e-3, 1.6e-3)


def example_loss_dp_pa() -> list[list[int]]:
    """The example tap line's loss dp_Pa[temp][flow] (Pa, rounded): 3 m of 12 mm bore plus
    fittings of K = 3, ISO VG46 at EXAMPLE_TEMPS_C, by the product's pipe-loss model
    (ropemon.commission.losses) and oil (ropemon.commission.oil)."""
    from ropemon.commission import losses
    from ropemon.commission.oil import Oil
    from ropemon.commission.site import Fitting, PipePath, PipeSegment

    pipe = PipePath(segments=(PipeSegment(length_m=3.0, bore_m=0.012, roughness_m=1.5e-6),),
                    fittings=(Fitting(kind="custom", bore_m=0.012, K=3.0),))
    oil = Oil.grade(46)
    return [[round(losses.pressure_loss_Pa(pipe, q, float(oil.rho_kg_m3(t)), float(oil.nu_m2_s(t))))
             for q in EXAMPLE_FLOWS_M3_S] for t in EXAMPLE_TEMPS_C]


def example_physical() -> dict:
    """The default physical section: the paper's field hoist (4 ropes, 8.18 t cage, 810 m).

    Choices, documented in docs/model.md ("Shipped default"):
    - bore 100 mm (A = 7.854e-3 m^2); empty cage at the pithead 185.4 kN, 46.4 kN
      per rope = 5.9 MPa; rated rope tension 100 kN (12.7 MPa).
    - 4-20 mA transmitters, 0-25 MPa and +-50 mm, read by ADS1115 across 150 ohm
      shunts: 4 mA = 9600 counts, 20 mA = 48000 counts (docs/model.md, ADC front end).
    - stroke 100 mm (end stops at +-50 mm, the transmitters' span), stroke-limit margin
      10 mm, travel tolerance 5 mm.
    - LuGre seal: Fs = 1.5 kN + 1.0 kN/MPa (7.4 kN at 5.9 MPa, which holds the
      pithead reading ~16 % low), Fc = 1.0 kN + 0.6 kN/MPa, vs = 2 mm/s falling
      0.04 mm/s per MPa, sigma2 = 20 + 2 kN s/m per MPa, sigma0 = 2e7 N/m
      (pre-sliding ~0.4 mm), sigma1 = 3e4 N s/m.
    - tap line 3 m x 12 mm with fittings; VG46 at 0/20/40 C (laminar: tenfold in
      viscosity; `example_loss_dp_pa`); temperature input not fitted, 20 C assumed.
    """
    area = math.pi * 0.1 ** 2 / 4
    temps = list(EXAMPLE_TEMPS_C)
    flows = list(EXAMPLE_FLOWS_M3_S)
    dp = example_loss_dp_pa()
    chan_p = {"counts_4mA": 9600, "counts_20mA": 48000, "range_Pa": [0.0, 25e6]}
    chan_x = {"counts_lo": 9600, "counts_hi": 48000, "range_m": [-0.05, 0.05]}
    return {
        "ropes": 4,
        "sample_hz": 200,
        "frame_hz": 10,
        "rated_rope_tension_N": 100000.0,
        "imbalance_frac": 0.10,
        "battery_low_V": 10.5,
        "cylinder_area_m2": [area] * 4,
        "adc_bits": 16,
        "pressure_channels": [dict(chan_p) for _ in range(4)],
        "displacement_channels": [dict(chan_x) for _ in range(4)],
        # the 100 mm the +-50 mm transmitters span: end stops at +-50 mm, the stroke-limit
        # band within 10 mm of each
        "stroke_m": [0.1] * 4,
        "stroke_margin_m": 0.01,
        "travel_tolerance_m": 0.005,
        "speed_m_per_pulse": 0.01,
        "hall_marks_m": [5.0, 200.0, 400.0, 600.0, 805.0],
        "battery_V_per_count": 2e-4,
        "temperature": None,
        "oil_temp_assumed_C": 20.0,
        "velocity_cutoff_hz": 5.0,
        "piston_speed_max_m_s": 0.2,
        "hoist_speed_max_m_s": 20.0,
        "hall_snap_m": 2.0,
        "start_depth_m": 0.0,
        "friction_cutoff_hz": 1.0,
        "displacement_noise_m": 2e-5,
        "friction_play_sigmas": 2.0,
        "friction": {
            "Fs": {"intercept": 1500.0, "slope": 1000.0},
            "Fc": {"intercept": 1000.0, "slope": 600.0},
            "vs": {"intercept": 0.002, "slope": -0.00004},
            "sigma2": {"intercept": 20000.0, "slope": 2000.0},
            "sigma0": 2.0e7,
            "sigma1": 3.0e4,
        },
        "loss": {"temps_C": temps, "flow_m3_s": flows, "dp_Pa": [dp for _ in range(4)]},
    }


def main() -> int:
    """Print the default node.json (the shipped firmware/node.json)."""
    json.dump(make_node_json(example_physical()), sys.stdout, indent=1)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
