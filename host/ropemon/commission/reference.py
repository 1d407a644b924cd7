"""The float64 oracle of the node's compensation (docs/model.md), from the `physical` section.

Same equations as firmware/ropenode, in floating point and SI units, with the
same discrete-time choices that are part of the model (filtered-position
velocity with the +-v_max/fs increment clamp, the noise-robust LuGre observer, table
interpolation of the loss, NAMUR limits, last-good hold on a failed channel, the
pressure read in the node's kPa/16 steps for the observer and the friction):

    T_i = p_tap,i A_i + dp_i(A_i v_i) A_i + F_i

`compensate(physical, records)` returns per-sample arrays; `decimate` the frame
window values; `run_stream(node_json, rsens_path)` both from files.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ropemon.firmware import node_module
from ropemon.commission.nodejson import (DEFAULTS, NOISE_CLIP, NOISE_RANGE, as_physical, namur_limits,
                                         physical_params, pressure_scale)
from ropemon.commission.seal import g, lines_at

RS = node_module("rsens")  # the .rsens format is firmware/ropenode/rsens.py's, never restated
RSENS_HEADER = struct.Struct(RS.HEADER)


@dataclass
class Compensated:
    """Per-sample results (rows = samples, columns = ropes); NaN where no tension."""

    tension_n: np.ndarray        # compensated T (N), NaN where the rope is not good
    raw_tension_n: np.ndarray    # p_tap * A (N), last good value held
    friction_n: np.ndarray       # LuGre F (N)
    loss_n: np.ndarray           # dp * A (N)
    p_pa: np.ndarray             # sensor pressure (Pa), last good value held
    v_m_s: np.ndarray            # filtered piston velocity
    good: np.ndarray             # bool: both loops healthy (and read once)
    fault_mask: np.ndarray       # int: bit i pressure, bit 4+i displacement
    held_n: np.ndarray | None = None  # the do-no-harm cut of F at rest (N), 0 where none


@dataclass
class Frames:
    """Per frame window and rope: tension mean/min/max (N) and raw pressure mean (Pa); NaN if absent."""

    mean_n: np.ndarray
    min_n: np.ndarray
    max_n: np.ndarray
    raw_pa: np.ndarray


def read_rsens(path: str | Path) -> tuple[int, int, np.ndarray]:
    """(ropes, sample_hz, records[k, 2N+4] uint16) of a .rsens file (docs/data-formats.md).
    ValueError names the file and the fault (not a regular file, larger than files.MAX_RSENS,
    not a version-1 stream of 1..4 ropes)."""
    from ropemon.station import files

    data = files.read_bytes(path, "sensor stream", files.MAX_RSENS, ValueError)
    if len(data) < RSENS_HEADER.size:
        raise ValueError(f"{path}: too short for a .rsens header ({len(data)} bytes < {RSENS_HEADER.size})")
    magic, version, ropes, hz, _ = RSENS_HEADER.unpack_from(data)
    if magic != RS.MAGIC or version != 1:
        raise ValueError(f"{path}: not a version-1 .rsens stream")
    if not 1 <= ropes <= 4 or hz == 0:
        raise ValueError(f"{path}: header says {ropes} ropes at {hz} Hz: not a valid stream")
    w = 2 * ropes + 4
    k = (len(data) - RSENS_HEADER.size) // (2 * w)  # a partial last record is ignored
    body = np.frombuffer(data, dtype="<u2", count=k * w, offset=RSENS_HEADER.size)
    return ropes, hz, body.reshape(k, w)


def _hold(values: np.ndarray, ok: np.ndarray, before: float = 0.0) -> np.ndarray:
    """Replace values where ~ok by the last ok value (before the first: `before`)."""
    idx = np.where(ok, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    out = np.where(idx >= 0, values[np.maximum(idx, 0)], before)
    return out


def _step_faults(counts: np.ndarray, namur_ok: np.ndarray, limit: int, recover: int) -> np.ndarray:
    """Samples where a pressure channel is faulted by an implausible step (docs/model.md,
    "Channels"), as the node decides it: a count within NAMUR more than `limit` from the
    last such count before it (none after a NAMUR fault) faults it until `recover` plausible
    steps have followed (limit 0: never)."""
    bad = np.zeros(len(counts), bool)
    if limit == 0:
        return bad
    prev, left = -1, 0
    for j, (c, ok) in enumerate(zip(counts.tolist(), namur_ok.tolist())):
        if not ok:
            prev = -1
            continue
        if prev >= 0:
            if abs(c - prev) > limit:
                left = recover
            elif left > 0:
                left -= 1
        prev = c
        bad[j] = left > 0
    return bad


def _temperature_c(ph: dict, counts: np.ndarray) -> np.ndarray:
    """Oil temperature per sample (C): the input where fitted and plausible, else the assumed."""
    assumed = float(ph["oil_temp_assumed_C"])
    t = ph.get("temperature")
    if t is None:
        return np.full(counts.shape, assumed)
    c0, cpc = float(t["counts_at_0C"]), float(t["counts_per_C"])
    lo, hi = sorted((c0 - 40 * cpc, c0 + 125 * cpc))
    lo_c, hi_c = max(0, math.ceil(lo)), min(65534, math.floor(hi))
    c = counts.astype(float)
    ok = (counts != 0xFFFF) & (c >= lo_c) & (c <= hi_c)
    return np.where(ok, (c - c0) / cpc, assumed)


def _loss_force(ph: dict, i: int, area: float, v: np.ndarray, temp_c: np.ndarray) -> np.ndarray:
    """dp_i(Q) * A_i: interpolated in flow (held beyond the table), then in temperature."""
    lo = ph["loss"]
    temps = np.asarray(lo["temps_C"], float)
    flows = np.asarray(lo["flow_m3_s"], float)
    dp = np.asarray(lo["dp_Pa"][i], float)
    q = np.abs(v) * area
    rows = np.stack([np.interp(q, flows, dp[t]) for t in range(len(temps))])  # (T, k)
    if len(temps) == 1:
        out = rows[0]
    else:
        tc = np.clip(temp_c, temps[0], temps[-1])
        j = np.clip(np.searchsorted(temps, tc, side="right") - 1, 0, len(temps) - 2)
        w = (tc - temps[j]) / (temps[j + 1] - temps[j])
        k = np.arange(len(q))
        out = rows[j, k] * (1 - w) + rows[j + 1, k] * w
    return np.sign(v) * out * area


def lugre_friction(fr: dict, p_pa: np.ndarray, dxs: np.ndarray, dxp: np.ndarray, vq: np.ndarray,
                   fs: float, limit: tuple | None = None) -> np.ndarray:
    """LuGre friction F (N) of one rope over samples, from the `friction` section `fr`.

    `p_pa` the pressure the parameter lines take (already held at the fit's top), `dxs`
    the per-sample increment of the LuGre position (elastic step), `dxp` that of its
    play (dissipation), `vq` the velocity of the viscous term; the seal starts unloaded.
    In zf = sigma0 z: elastic step, implicit-Euler dissipation, |zf| <= g;
    F = zf + sigma1 dz/dt + sigma2 v (docs/model.md); the lines and g(v) are
    ropemon.commission.seal's. `limit` (dx, rest, good per sample, play): the do-no-harm limit
    (`do_no_harm`): F is returned with F limited and the held-back cut [sample] (N)."""
    sigma0, sigma1 = float(fr["sigma0"]), float(fr["sigma1"])
    h = 1.0 / fs
    c1 = sigma1 / (sigma0 * h)
    f_static, f_coulomb, v_stribeck, sigma2 = lines_at(fr, np.asarray(p_pa, float) / 1e6)
    # g at the velocity of x_s: g at the noisy v would dip with every noise peak and
    # the bound |zf| <= g would ratchet zf down
    gv = g(dxs * fs, f_static, f_coulomb, v_stribeck)
    zn = np.empty(len(gv))
    z = 0.0
    for j, (gj, wj, wd) in enumerate(zip(gv.tolist(), (sigma0 * dxs).tolist(),
                                         (sigma0 * np.abs(dxp)).tolist())):
        z = (z + wj) * gj / (gj + wd)
        z = gj if z > gj else (-gj if z < -gj else z)
        zn[j] = z
    zprev = np.concatenate(([0.0], zn[:-1]))
    f = zn + c1 * (zn - zprev) + sigma2 * vq
    if limit is None:
        return f
    return (f, *do_no_harm(f, gv, *limit, sigma0=sigma0))


def do_no_harm(f: np.ndarray, gv: np.ndarray, dx: np.ndarray, rest: np.ndarray, good: np.ndarray,
               play: float, sigma0: float) -> tuple:
    """The node's do-no-harm limit (docs/model.md, "Do no harm") on one rope's friction F (N):
    zm, the seal state the piston's own travel gives (the velocity filter's x_f through a play
    of half-width `play`, in the LuGre steps of zf with the same g; kept across a loop fault,
    its play re-anchored at each start), and at rest F keeps only what zm holds the same way,
    give or take twice sigma0 times the play.
    Returns (F limited, the cut per sample, N); `play` 0: no limit."""
    out = np.array(f, dtype=float)
    cut = np.zeros(len(out))
    if play <= 0:
        return out, cut
    # where the model is right zm still parts from zf: its elastic step follows x_f's noise (sigma0
    # times it, within sigma0 play) and its dissipation waits for x_f to cross the play (sigma0 play
    # more), so within twice sigma0 play of zm the channels do not contradict the model
    tol = 2.0 * sigma0 * play
    zm = xm = xp = 0.0
    started = False
    for j, (fj, gj, xj, rj, okj) in enumerate(zip(f.tolist(), gv.tolist(), dx.tolist(), rest.tolist(),
                                                  good.tolist())):
        if not okj:
            started = False
            continue
        if not started:
            xm = xp = 0.0
            started = True
        xm += xj
        dp = xm - play - xp if xm > xp + play else (xm + play - xp if xm < xp - play else 0.0)
        xp += dp
        zm = (zm + sigma0 * xj) * gj / (gj + sigma0 * abs(dp))
        zm = min(max(zm, -gj), gj)
        if rj:
            lim = max(zm + tol, 0.0) if fj > 0 else min(zm - tol, 0.0)
            if (fj > 0 and fj > lim) or (fj < 0 and fj < lim):
                cut[j] = abs(fj - lim)
                out[j] = lim
    return out, cut


def hoist_at_rest(ph: dict, records: np.ndarray, n: int) -> np.ndarray:
    """Per sample, as the node decides it before the sample's counter word: no shaft pulse in
    the frame window so far nor in the window before (a jump beyond the most pulses per
    sample is a counter glitch, not travel)."""
    p = as_physical(ph)
    fs = int(p.sample_hz)
    win = fs // int(p.frame_hz)
    maxp = math.ceil(p.setting("hoist_speed_max_m_s") / p.speed_m_per_pulse / fs) + 1
    c = records[:, 2 * n + 2].astype(np.int64)
    d = np.zeros(len(c), np.int64)
    d[1:] = (c[1:] - c[:-1]) & 0xFFFF
    d[d >= 0x8000] -= 0x10000
    pulses = np.where(np.abs(d) <= maxp, np.abs(d), 0)
    rest = np.zeros(len(c), bool)
    this = last = 0
    for j, q in enumerate(pulses.tolist()):
        rest[j] = this == 0 and last == 0
        this += q
        if (j + 1) % win == 0:
            this, last = 0, this
    return rest


@dataclass
class Follow:
    """The node's stroke decisions, for the reference to take where the two decide apart
    only because their values part by rounding.

    Per sample: `tracking` whether the node tracked strokes (every rope healthy, started
    and warmed up), `state` its (mode, direction, count) after the sample (kernel.py's
    _SMODE, _SSGN, _SCNT), and `e` (per rope, m) and `cl` (m per sample) as its decision
    compared them. Where the reference's decision differs from the node's and
    `stroke_decision` on the node's `e` and `cl`, from the reference's state before the
    sample, gives the node's: the reference takes the node's (its sample listed in
    `followed`). Any other difference, and any sample where one tracks and the other does
    not, is the node deciding otherwise than its model: listed in `disputes` (sample, the
    reference's, the node's), the reference keeping its own."""

    tracking: np.ndarray
    state: np.ndarray
    e: np.ndarray
    cl: np.ndarray
    followed: list = field(default_factory=list)
    disputes: list = field(default_factory=list)


def stroke_decision(state: tuple, e: list, cl: float, th: float, vmin: float, settle: int) -> tuple:
    """The stroke tracking's (mode, direction, count) after a sample, from those before it,
    each rope's e (m, after the take-over) and the common motion's low-pass cl (docs/model.md,
    "Balancing strokes"). A stroke starts, after the direction held `settle` samples while
    moving (|cl| > vmin), when exactly one rope's e is past the threshold that way (two alike
    tie within rounding); it ends when the direction turns or another rope's e passes it."""
    mode, sgn, cnt = state
    s = 1 if cl > 0 else -1
    if mode == 0:
        moving = abs(cl) > vmin
        if moving and s != sgn:
            sgn, cnt = s, 0
        elif cnt < settle:
            cnt += 1
        if moving and cnt >= settle:
            past = [i for i in range(len(e)) if e[i] * s > th]
            if len(past) == 1:
                mode = past[0] + 1
        return mode, sgn, cnt
    end = False
    if s != sgn:
        end, cnt = True, 0
    if any(e[i] * sgn > th for i in range(len(e)) if i != mode - 1):  # another piston moves
        end = True
    return (0, s, cnt) if end else (mode, sgn, cnt)


def compensate(ph: dict, records: np.ndarray, strokes: list | None = None,
               increments: dict | None = None, tracker_class: type | None = None,
               follow: Follow | None = None) -> Compensated:
    """Run the model over records[k, 2N+4] (uint16 words) with physical section `ph`.

    `strokes`, a list, receives (sample, rope or -1, e per rope in m) for every start
    (rope 0-based) and end (-1, also by a fault or a restart) of a balancing stroke (`ropemon study stroke-events`).
    `increments`, a dict, receives the observer's per-sample increments [sample, rope]
    (m): "dxs" of the LuGre position and "dxp" of its play (`ropemon study observer-losses`),
    "noise_ratio"[sample], the noise following's ratio (1: as commissioned), and after each
    sample "e"[sample, rope] (m; zeroed where a stroke starts or ends) and "cl"[sample]
    (m per sample), what the stroke decisions compare.
    `follow` (Follow) gives the node's stroke decisions, taken where the two decide apart
    only by rounding.
    `tracker_class` takes the place of `PressureTracker` (the same constructor and `step`):
    a lab study's stand-in for the node's pressure tracker.

    Slide following (physical `slide_follow`, `slide_follow_lo_sigmas` 3, `_hi_sigmas` 5,
    as the node): outside a stroke, what e holds beyond a quarter of the stroke threshold
    is taken into x_h at 1/64 per sample, and a share f = clip((|e| - lo) / (hi - lo), 0, 1)
    of it (lo, hi in e's rms noise) enters as seal travel (x_s and the play, next sample)
    instead of re-anchoring x_h."""
    pp = physical_params(ph)
    phys = as_physical(ph)
    n = pp["ropes"]
    fs = float(ph["sample_hz"])
    p_max = pp["p_max_pa"]
    areas = [float(a) for a in ph["cylinder_area_m2"]]
    fr = ph["friction"]
    k = records.shape[0]
    temp_c = _temperature_c(ph, records[:, 2 * n + 1])
    shape = (k, n)
    out = {name: np.zeros(shape) for name in ("tension", "raw", "fric", "loss", "p", "v")}
    good = np.zeros(shape, bool)
    fault = np.zeros(k, int)
    P = np.zeros(shape)
    X = np.zeros(shape)
    PQ = np.zeros(shape)
    OK = np.zeros(shape, bool)
    POK = np.zeros(shape, bool)
    for i in range(n):
        pc = ph["pressure_channels"][i]
        c4, c20 = pc["counts_4mA"], pc["counts_20mA"]
        plo, phi = pc["range_Pa"]
        flo, fhi = namur_limits(c4, c20)
        cp = records[:, i].astype(float)
        p_ok = (cp >= flo) & (cp <= fhi)
        # an implausible step is a fault as NAMUR's limits are (the node compares counts)
        p_ok &= ~_step_faults(records[:, i], p_ok, pp["pressure_step_counts"][i], pp["pressure_step_recover"])
        P[:, i] = _hold(plo + (cp - c4) * (phi - plo) / (c20 - c4), p_ok)
        # the pressure as the node reads it for its observer and friction, in kPa/16 steps
        # (its gain within 3e-5 and its 4 mA value within 500 Pa of the channel's range: the
        # median the pressure tracker takes must be the node's, or its bounce parts from the
        # node's where the median passes from one pair of channels to another); the tension's
        # p A is the node's own product of the counts, as exact as the float one
        k4, km, ks = pressure_scale(phys.pressure_channels[i], f"physical.pressure_channels[{i}]")
        kpa16 = (k4 << 4) + (((records[:, i].astype(np.int64) - c4) * km) >> (ks - 4))
        PQ[:, i] = _hold(kpa16 * (1000.0 / 16), p_ok)
        dc = ph["displacement_channels"][i]
        clo, chi = dc["counts_lo"], dc["counts_hi"]
        xlo, xhi = dc["range_m"]
        dlo, dhi = namur_limits(clo, chi)
        cx = records[:, n + i].astype(float)
        x_ok = (cx >= dlo) & (cx <= dhi)
        X[:, i] = xlo + (cx - clo) * (xhi - xlo) / (chi - clo)
        fault |= np.where(p_ok, 0, 1 << i) | np.where(x_ok, 0, 16 << i)
        good[:, i] = p_ok & x_ok & np.maximum.accumulate(p_ok) & np.maximum.accumulate(x_ok)
        OK[:, i] = p_ok & x_ok
        POK[:, i] = p_ok
    DX, DXS, DXP, NR, EV, CL = _observer(pp, PQ, X, OK, POK, fs, strokes, tracker_class or PressureTracker,
                                         follow)
    if increments is not None:
        increments.update(dxs=DXS, dxp=DXP, noise_ratio=NR, e=EV, cl=CL)
    rest = hoist_at_rest(ph, records, n)
    held_n = np.zeros(shape)
    for i in range(n):
        p = P[:, i]
        dx, dxs, dxp = DX[:, i], DXS[:, i], DXP[:, i]
        v = dx * fs
        # the velocity of the pipe loss and the viscous term: with a compliance that of
        # the LuGre position, from the pressure (the displacement's noise would pass)
        vq = dxs * fs if pp["compliance"][i] else v
        # the friction's pressure in whole kPa, as the node takes it (and clamps it)
        p_kpa = np.clip(np.floor(PQ[:, i] / 1000.0), 0.0, math.ceil(p_max / 1000.0))
        fric, shown, held_n[:, i] = lugre_friction(fr, p_kpa * 1000.0, dxs, dxp, vq, fs,
                                                   (dx, rest, OK[:, i], pp["hold_play_m"]))
        loss = _loss_force(ph, i, areas[i], vq, temp_c)
        raw = p * areas[i]
        ok = good[:, i]
        out["tension"][:, i] = np.where(ok, raw + loss + shown, np.nan)
        out["raw"][:, i] = raw
        out["fric"][:, i] = fric
        out["loss"][:, i] = loss
        out["p"][:, i] = p
        out["v"][:, i] = v
    return Compensated(out["tension"], out["raw"], out["fric"], out["loss"], out["p"],
                       out["v"], good, fault, held_n)



class PressureTracker:
    """The node's pressure tracker in floats (docs/model.md, "Pressure tracker"), with its
    quantised gains `tr` (nodejson.tracker_gains; None: no compliance, p_l stays 0):
    a steady-state Kalman filter of the median pressure as a creep at a constant rate plus
    the rope bounce, a damped oscillator. It starts afresh at the first median after none."""

    def __init__(self, tr: dict | None):
        self.on = False
        self.c = self.v = self.b0 = self.b1 = 0.0
        self.tr = tr
        if tr is not None:
            k = tr["k_q14"]
            self.a1, self.a2 = tr["a1_q14"] / 16384, tr["a2_q14"] / 16384
            self.k = (k[0] / 16384, k[1] / (1 << (14 + tr["v_shift"])),
                      k[2] / (1 << (14 + tr["b_shift"])), k[3] / (1 << (14 + tr["b_shift"])))
            # the node's clamps (kernel.py), in Pa: the innovation, c and v within +-2**28 of
            # their units (c in kPa/2048, v 2**v_shift finer), the bounce b within +-2**26 of
            # its (2**b_shift finer than c)
            unit = 1000.0 / 2048
            self.lim_c = (1 << 28) * unit
            self.lim_v = (1 << 28) * unit / (1 << tr["v_shift"])
            self.lim_b = (1 << 26) * unit / (1 << tr["b_shift"])

    def step(self, y: float | None) -> float:
        """The estimate p_l after the median `y` (Pa; None: no healthy channel)."""
        if self.tr is None:
            return 0.0
        if y is None:
            self.on = False
        elif not self.on:
            self.on = True
            self.c = y
            self.v = self.b0 = self.b1 = 0.0
        else:
            c = self.c + self.v
            b0, self.b1 = self.a1 * self.b0 - self.a2 * self.b1, self.b0
            e = _clamp(y - c - b0, self.lim_c)  # a step beyond any pressure (131 MPa)
            k0, kv, k2, k3 = self.k
            self.c = _clamp(c + k0 * e, self.lim_c)
            self.v = _clamp(self.v + kv * e, self.lim_v)
            self.b0 = _clamp(b0 + k2 * e, self.lim_b)
            self.b1 = _clamp(self.b1 + k3 * e, self.lim_b)
        return min(max(self.c + self.b0, -P_L_MAX_PA), P_L_MAX_PA)


def _clamp(v: float, lim: float) -> float:
    return lim if v > lim else (-lim if v < -lim else v)


P_L_MAX_PA = 1e8  # p_l is held within +-100 MPa, as the node holds it (kernel.py)


def _median(values: list) -> float:
    """The median (of an even count: the mean of the middle two); 0 for none."""
    v = sorted(values)
    m = len(v)
    if m == 0:
        return 0.0
    return v[m // 2] if m % 2 else 0.5 * (v[m // 2 - 1] + v[m // 2])


REST_D_MAX = 64e-6  # |x_s - x_l| is clamped here for the activity (as the node: 2**14 um/256)


# The observer, stage by stage as firmware/ropenode/kernel.py's `step` runs them (each
# stage's function names the kernel's comment that opens it). The kernel's other stages
# are the reference's too, outside the observer: the channels (counts, NAMUR, the
# implausible step) and the oil temperature in `compensate`, the pipe loss in
# `_loss_force`, the LuGre friction in `lugre_friction`, the tension in `compensate` and
# the window statistics in `decimate`.
#
#   kernel.py step                                      reference
#   the LuGre position's pressure part: the median      _pressure_median_and_noise
#   noise following; the play for the median's noise    _pressure_median_and_noise
#   the pressure tracker                                PressureTracker.step
#   k p_l and its step: the oil's common motion         _common_motion
#   a balancing stroke (mode 0 unless allw)             _observer
#   per rope: velocity x_f                              _velocity
#   per rope: the LuGre's position x_h = k p_l + b      _lugre_position
#   per rope: the rest hold's play and activity         _rest_hold_and_play
#   balancing strokes: cl, take-over, decision          _balancing_strokes
#     ... slide following's take-over (mode 0)          _take_over
#     ... a stroke's start: the stopped pistons' e      _stroke_start_offsets


class _ObserverState:
    """The observer's settings and its state between samples, per rope (lists) and common
    (the kernel's S words named in comments), and its per-sample outputs."""

    def __init__(self, pp: dict, k: int, n: int, fs: float, tracker_class: type):
        self.n = n
        # noise following: the level per channel (_NL), its last two pressures (_NP1,
        # _NP2) and how many of them it has (_NRUN); the ratio (NOISE_Q10)
        self.nref, self.nsh = pp["noise_ref_pa"], pp["noise_shift"]
        self.a_n = 2.0 ** -self.nsh
        self.lv, self.p1, self.p2, self.run = [self.nref] * n, [0.0] * n, [0.0] * n, [0] * n
        self.ratio = 1.0
        self.alpha, self.dx_max, self.plays = pp["alpha"], pp["v_max"] / fs, pp["plays_m"]
        self.rest, self.rest_plays = pp["rest_m"], pp["rest_plays_m"]
        self.alpha_l, self.alpha_a = pp["alpha_l"], pp["alpha_a"]
        self.alpha_z, self.alpha_e, self.warm = pp["alpha_z"], pp["alpha_e"], pp["warmup"]
        self.tracker = tracker_class(pp["tracker"])
        self.kh, self.aw = pp["compliance"], pp["area_w"]
        self.th, self.vmin, self.settle = pp["stroke_m"], pp["stroke_vmin"], pp["stroke_settle"]
        # slide following: what e holds beyond lo .. lo + span (times its noise) is proven
        # travel of the piston: that share of the take-over goes in as seal travel (through
        # x_s and the play), not re-anchored (span 0: off)
        self.sl_lo, self.sl_span = pp["slide_lo_m"], pp["slide_span_m"]
        # per rope: _STARTED, XF, XS, XP, _XH, _PL, _XB, _E, _MOT, _XL, _ACT, _WARM
        self.started = [False] * n
        self.xf, self.xs, self.xp, self.xh, self.pl, self.xb, self.e, self.mot, self.xl, self.act = (
            [0.0] * n for _ in range(10))
        self.w = [0] * n
        # the stroke tracking: _CL, _SMODE, _SSGN, _SCNT
        self.cl, self.mode, self.sgn, self.cnt = 0.0, 0, 0, 0
        # outputs per sample
        self.nr = np.ones(k)
        self.dx = np.zeros((k, n))
        self.dxs = np.zeros((k, n))
        self.dxp = np.zeros((k, n))
        self.ev = np.zeros((k, n))
        self.clv = np.zeros(k)


def _pressure_median_and_noise(s: _ObserverState, j: int, pr: list, pokr: list) -> tuple:
    """kernel.py step, "the LuGre position's pressure part first ... the median of the
    healthy pressure channels", "noise following" and "the play, and the rest hold's play
    and threshold, for the noise of this median": (the median or None for no healthy
    channel, play, rest play, rest threshold)."""
    n = s.n
    healthy = [p for p, ok in zip(pr, pokr) if ok]
    pm = _median(healthy)
    c = len(healthy) - 1 if healthy else n - 1  # the median of fewer is noisier
    if s.nsh:
        # noise following: each healthy channel's level, a low-pass of its clipped
        # |second difference|, within 1/NOISE_RANGE .. NOISE_RANGE of nref; the plays
        # and the threshold scale by the healthy channels' median level over nref
        lv, p1, p2, run, nref = s.lv, s.p1, s.p2, s.run, s.nref
        for i in range(n):
            if not pokr[i]:
                run[i] = 0
                continue
            if run[i] == 2:
                d = min(abs(pr[i] - 2 * p1[i] + p2[i]), NOISE_CLIP * lv[i])
                lv[i] = min(max(lv[i] + s.a_n * (d - lv[i]), nref / NOISE_RANGE), NOISE_RANGE * nref)
            else:
                run[i] += 1
            p2[i], p1[i] = p1[i], pr[i]
        if healthy:
            s.ratio = math.floor(_median([lv[i] for i in range(n) if pokr[i]]) / nref * 1024) / 1024
        s.nr[j] = s.ratio
    ratio = s.ratio
    play, rest_play, hold = s.plays[c] * ratio, s.rest_plays[c] * ratio, s.rest[c] * ratio
    return (pm if healthy else None), play, rest_play, hold


def _common_motion(s: _ObserverState, xr: list, okr: list, pk: float) -> tuple:
    """kernel.py step, "k p_l ... and its step this sample; their sum over the ropes,
    weighted by area, is the oil's common motion", with a rope's (re)start after a loop
    fault: (cv, allw), allw whether every rope is healthy, started before and warmed up
    (and strokes are tracked: `if P[_STH] == 0: allw = 0`)."""
    kh, pl, mot, w = s.kh, s.pl, s.mot, s.w
    cv = 0.0
    allw = s.th > 0
    for i in range(s.n):
        if not okr[i]:
            s.started[i] = False  # after a loop fault the filters start again, the seal state is kept
            allw = False
            continue
        if not s.started[i]:
            s.started[i] = True
            s.xf[i] = s.xs[i] = s.xp[i] = s.xh[i] = s.xl[i] = xr[i]
            s.act[i] = REST_D_MAX  # not quiet until the activity has settled
            pl[i] = pk
            s.xb[i] = xr[i] - kh[i] * pl[i]
            w[i] = 0
            s.e[i] = 0.0
            allw = False
        m = kh[i] * pl[i]
        pl[i] = pk
        mot[i] = _clamp(kh[i] * pl[i] - m, s.dx_max)
        cv += mot[i] * s.aw[i]
        if w[i] < s.warm:
            allw = False
    return cv, allw


def _velocity(s: _ObserverState, j: int, i: int, x: float) -> None:
    """kernel.py step, per rope, "velocity: x_f += alpha (x - x_f), increment clamped to
    +-dx_max"."""
    step = _clamp(s.alpha * (x - s.xf[i]), s.dx_max)
    s.xf[i] += step
    s.dx[j, i] = step


def _lugre_position(s: _ObserverState, j: int, i: int, hold: float) -> int:
    """kernel.py step, per rope, "the LuGre's position x_h = k p_l + b": how quiet by the
    rest hold's activity (qt), b in a stroke and its low-pass (the warm-up's running mean),
    x_h, "e: low-pass of x_f - x_h" and x_s's clamped step. Returns how quiet (0 .. 256)."""
    xf, xb, xh, w = s.xf, s.xb, s.xh, s.w
    kp = s.kh[i] * s.pl[i]
    a = s.alpha_z
    # how quiet (0 .. 256): the whole hold below `hold`, none from twice it, by the
    # activity of the last sample, in the node's steps
    q = 0
    if hold > 0:
        q = 256 if s.act[i] <= hold else max(0, math.floor(256 * (2 * hold - s.act[i]) / hold))
    if s.mode > 0:  # a stroke: the stopped ropes stand, the sliding one's b stands
        if i != s.mode - 1:
            xb[i] -= s.mot[i]
        else:
            a = 0.0
    if w[i] < s.warm:
        a = max(s.alpha_z, 1.0 / (w[i] + 1))
    elif q:  # at rest b stands: its wander would be seal travel
        a = (round(a * 16384) * (256 - q) // 256) / 16384
    inc = a * (xf[i] - kp - xb[i])
    xb[i] += inc
    step = kp + xb[i] - xh[i]
    xh[i] += step
    if w[i] < s.warm:
        step -= inc
        w[i] += 1
    s.e[i] += s.alpha_e * (xf[i] - xh[i] - s.e[i])
    step = _clamp(step, s.dx_max)
    s.xs[i] += step
    s.dxs[j, i] = step
    return q


def _rest_hold_and_play(s: _ObserverState, j: int, i: int, q: int, play: float, rest_play: float) -> None:
    """kernel.py step, per rope, "the rest hold's play widens with qt; its activity: the
    low-pass of |x_s - x_l|, x_l a slower low-pass of x_s", then the play x_p (dx_p)."""
    xs, xp = s.xs, s.xp
    # the rest hold's activity: low-pass of |x_s - x_l|, x_l a slower low-pass of x_s
    s.xl[i] += s.alpha_l * (xs[i] - s.xl[i])
    s.act[i] += s.alpha_a * (min(abs(xs[i] - s.xl[i]), REST_D_MAX) - s.act[i])
    wp = play + (rest_play - play) * q / 256
    if xs[i] > xp[i] + wp:
        s.dxp[j, i] = xs[i] - wp - xp[i]
    elif xs[i] < xp[i] - wp:
        s.dxp[j, i] = xs[i] + wp - xp[i]
    xp[i] += s.dxp[j, i]


def _take_over(s: _ObserverState) -> None:
    """kernel.py step, balancing strokes, `if mode == 0:` "what e holds beyond a quarter of
    the threshold ... x_h takes it over at 1/64 per sample ... Slide following"."""
    e, th, sl_lo, sl_span = s.e, s.th, s.sl_lo, s.sl_span
    # e beyond a quarter of the threshold (noise: 1.6 sigma) is real unequal
    # sharing: x_h takes it over at 1/64 per sample; with slide following the
    # share f of it is left out of x_h: x_h's next step carries it into x_s
    for i in range(s.n):
        a = abs(e[i]) - th / 4
        if a > 0:
            f = min(max((abs(e[i]) - sl_lo) / sl_span, 0.0), 1.0) if sl_span > 0 else 0.0
            a = math.copysign(a / 64, e[i])
            s.xb[i] += a
            s.xh[i] += a * (1 - f)
            e[i] -= a


def _stroke_start_offsets(s: _ObserverState) -> None:
    """kernel.py step, balancing strokes, `if best > 0:` "until the stroke was seen the
    stopped pistons' x_h went on with the pressure: their offset is the stroke piston's
    lead shared by area ... plus the lag of e": the stopped ropes' e."""
    n, mode, aw, e = s.n, s.mode, s.aw, s.e
    # the stopped pistons' x_h went on with the pressure until the stroke was
    # seen: their offset is the stroke piston's lead shared by area, plus the
    # lag of e (a low-pass) behind that ramp
    # in the node's steps (kernel.py): the area ratio in Q8 and the lead in um/256
    # (floored), the common
    # motion per unit area in um/4096 (floored, |cl| held within 2**25 and the
    # quotient within 65535 of the node's units) and the lag in um/256 (floored):
    # a systematic offset of up to ~0.01 um otherwise, which x_h keeps and the
    # next stroke threshold sees
    others = sum(aw[i] for i in range(n) if i != mode - 1)
    if others > 0:
        aq = [round(a * 256) for a in aw]
        so = sum(aq) - aq[mode - 1]
        ae = round(s.alpha_e * 16384)
        c = _clamp(s.cl * 256e6 * 256, float(1 << 25))
        t = _clamp(float(math.floor(16 * c / sum(aq))), 65535.0)
        lag = math.floor(t * (16384 - ae) / (ae << 4)) / 256e6
        lead = math.floor(e[mode - 1] * 256e6 * ((aq[mode - 1] << 8) // so) / 256) / 256e6
        for i in range(n):
            if i != mode - 1:
                e[i] = -lead - lag


def _balancing_strokes(s: _ObserverState, j: int, cv: float, allw: bool, strokes: list | None,
                       follow: Follow | None) -> None:
    """kernel.py step, "balancing strokes": `if allw == 0:` the tracking's state and cl
    zeroed; else cl, the low-pass of the common motion, the take-over (no stroke), the
    stroke decision (`stroke_decision`, the node's taken per `follow`), a start's stopped
    pistons' e, and "a stroke starts or ends: x_h re-anchored by e, without seal travel"."""
    n, e = s.n, s.e
    apart = follow is not None and bool(follow.tracking[j]) != allw
    if apart:  # no comparison decides this
        follow.disputes.append((j, "tracking" if allw else "not tracking",
                                "tracking" if follow.tracking[j] else "not tracking"))
    if not allw:
        s.mode, s.sgn, s.cnt, s.cl = 0, 0, 0, 0.0
        return
    s.cl += s.alpha_e * (cv - s.cl)
    if s.mode == 0:
        _take_over(s)
    was = (s.mode, s.sgn, s.cnt)
    s.mode, s.sgn, s.cnt = stroke_decision(was, e, s.cl, s.th, s.vmin, s.settle)
    if follow is not None and not apart:  # (a sample disputed above is not compared again)
        node = tuple(int(v) for v in follow.state[j])
        if (s.mode, s.sgn, s.cnt) != node:
            # the same decision on the node's values: the two part by rounding only
            if stroke_decision(was, follow.e[j].tolist(), float(follow.cl[j]), s.th, s.vmin,
                               s.settle) == node:
                follow.followed.append(j)
                s.mode, s.sgn, s.cnt = node
            else:
                follow.disputes.append((j, (s.mode, s.sgn, s.cnt), node))
    re = s.mode != was[0]
    if re and strokes is not None:
        strokes.append((j, s.mode - 1, list(e)))
    if re and s.mode > 0:
        _stroke_start_offsets(s)
    if re:  # a stroke starts or ends: x_h re-anchored by e, without seal travel
        for i in range(n):
            s.xb[i] += e[i]
            s.xh[i] += e[i]
            e[i] = 0.0


def _observer(pp: dict, P: np.ndarray, X: np.ndarray, OK: np.ndarray, POK: np.ndarray, fs: float,
              strokes: list | None = None, tracker_class: type | None = None, follow: Follow | None = None):
    """Piston increments (dx, dx_s, dx_p)[sample, rope] of the velocity filter, the LuGre
    position x_h = k p_l + b (p_l the pressure tracker's estimate of the median of the
    healthy pressure channels) and its play, with the balancing-stroke tracking and the
    rest hold (docs/model.md); also the noise ratio [sample], e [sample, rope] and cl
    [sample] after each sample.

    Runs while both loops of a rope are healthy and starts again (with its warm-up)
    after a fault of either; strokes are tracked only while every rope runs warmed up.
    Each sample runs the kernel's stages in the kernel's order (see the table above)."""
    k, n = P.shape
    s = _ObserverState(pp, k, n, fs, tracker_class or PressureTracker)
    for j, (xr, pr, okr, pokr) in enumerate(zip(X.tolist(), P.tolist(), OK.tolist(), POK.tolist())):
        y, play, rest_play, hold = _pressure_median_and_noise(s, j, pr, pokr)
        pk = s.tracker.step(y)  # kernel.py: "the pressure tracker"
        cv, allw = _common_motion(s, xr, okr, pk)
        # kernel.py: "a balancing stroke ...": `if allw == 0: mode = 0`
        if not allw:
            if s.mode > 0 and strokes is not None:  # a fault or a restart ends the stroke
                strokes.append((j, -1, list(s.e)))
            s.mode = 0
        for i in range(n):  # kernel.py: the per-rope loop, its observer part
            if not okr[i]:
                continue
            _velocity(s, j, i, xr[i])
            q = _lugre_position(s, j, i, hold)
            _rest_hold_and_play(s, j, i, q, play, rest_play)
        _balancing_strokes(s, j, cv, allw, strokes, follow)
        s.ev[j] = s.e
        s.clv[j] = s.cl
    return s.dx, s.dxs, s.dxp, s.nr, s.ev, s.clv


def decimate(ph: dict, comp: Compensated) -> Frames:
    """Frame-window mean/min/max of the good samples (NaN for a window with none)."""
    win = int(ph["sample_hz"]) // int(ph["frame_hz"])
    k = comp.tension_n.shape[0] // win * win
    t = comp.tension_n[:k].reshape(k // win, win, -1)
    p = np.where(comp.good, comp.p_pa, np.nan)[:k].reshape(k // win, win, -1)
    with np.errstate(all="ignore"):
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return Frames(np.nanmean(t, axis=1), np.nanmin(t, axis=1), np.nanmax(t, axis=1),
                          np.nanmean(p, axis=1))


def run_stream(node_json: dict, rsens_path: str | Path) -> tuple[Compensated, Frames]:
    """Compensate and decimate a whole .rsens stream with a node.json's physical section."""
    ph = node_json["physical"]
    ropes, hz, recs = read_rsens(rsens_path)
    if ropes != ph["ropes"] or hz != ph["sample_hz"]:
        raise ValueError(f"{rsens_path}: {ropes} ropes at {hz} Hz, config says "
                         f"{ph['ropes']} at {ph['sample_hz']}")
    comp = compensate(ph, recs)
    return comp, decimate(ph, comp)


__all__ = ["Compensated", "Frames", "compensate", "decimate", "read_rsens", "run_stream",
           "DEFAULTS"]
