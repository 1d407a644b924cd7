"""Hydraulic compliance k (m/Pa) of each cylinder, fitted from a recorded sensor stream.

The oil in a cylinder, its hoses and the connecting assembly compresses with
pressure, so a piston moves by k dp when its pressure changes (docs/model.md,
"LuGre (noise-robust observer)"). Oil with entrained air makes k uncertain by tens of per cent
from the drawings, so the node's k is measured from a recorded wind, on the node's own channel
scaling: a least-squares line of the piston position on the pressure, with an
offset of its own per piece of at most PIECE_S, over the parts of the wind where
no piston runs off its line. The cylinders share one manifold, so in long
decompressions one piston at a time takes all of the common motion while the
others stick (a balancing stroke), and a piston may creep; those stretches (and
STROKE_PAD_S around them) are left out, and the fit says how much of the
recording it used. That sum_i A_i x_i follows sum_i A_i k_i p_i over the whole
recording (the oil's volume is kept) is checked and warned when it does not. Where
the ropes part through the wind (groove creep: the pistons move differentially all
through it) too little is left to give a rope's own k; the fit then falls back, with a
warning and `method: "common"`, to the manifold's common compliance K = sum A_i k_i (the
slope of sum A_i x_i on the median pressure, where differential motions cancel), split
in equal volume shares k_i = K / (n A_i), and refuses only when K is not determined. The
same recording gives the pressure channels' noise, which sizes the play of the
node's friction observer (`pressure_noise_Pa`: the median channel's, as the node's
observer follows the median pressure and its noise following the median channel's
level; one noisier transmitter does not widen it), and the displacement channels'
noise, which sizes its thresholds on the displacement (`displacement_noise_m`),
and the cage's bounce at the pithead (`bounce_hz`), which tunes the node's
pressure tracker: the strongest line between 1 Hz and sample_hz/8 in the median
pressure over the first 4 s after the hoist stops at the end of the recording
(its arrival). A recording without such a stop, or where the line does not stand
out, gives no `bounce_hz` (`null`), and the node keeps its default.

    ropemon fit-compliance NODE.json SENSORS.rsens [--out compliance.json] [--check]

It prints the fit as JSON. When NODE.json was itself built with a compliance fit,
the command also re-checks it: it prints on stderr how far k, the pressure noise
and the bounce have moved since, and names those beyond the `RECHECK_*` tolerances
(`--check`: exit 1 then), so a wind recorded in service tells whether the node's
config is still right (docs/commissioning.md, "Re-check in service").

`fit(physical, records)` returns a `ComplianceFit` or raises `ComplianceError`
naming the rope and the reason (too little pressure change, a poor fit); the
command then exits 2 and writes nothing. SITE.toml names the output in its
`[compliance]` table (ropemon.commission.site), `ropemon config` puts it in `physical`.
"""
from __future__ import annotations

import argparse
import json
import math
import struct
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ropemon.commission.nodejson import namur_limits, physical_params
from ropemon.station.protocol import L
from ropemon.commission.reference import read_rsens
from ropemon.station import files

MIN_SPAN_PA = 0.3e6   # the pressure must change at least this much over the recording
MIN_R = 0.5           # correlation of position and pressure below which the fit is refused
MAX_REL_SE = 0.02     # standard error of k over k above which the fit is refused
BLOCK_S = 0.1             # the position and pressure are averaged over blocks this long
STROKE_SPAN_S = 2.0       # a rope's departure from its line is measured between means this long
STROKE_SIGMAS = 6.0       # ... and a block is left out where it runs off faster than this many rms
STROKE_MIN_M_S = 5e-6     # ... or this speed, whichever is larger
STROKE_PAD_S = 1.0        # left out around a departure (its start and end)
STROKE_SHARE = 0.75       # a piston that takes this share of the common motion strokes
PIECE_S = 10.0            # k is fitted with an offset of its own per piece this long at most (slow creep)
MAX_VOLUME_DEV = 0.03     # sum A_i x_i against sum A_i k_i p_i: warned beyond this, relative
BOUNCE_WINDOW_S = 4.0     # the arrival's bounce is looked for over this long after the stop
BOUNCE_MIN_HZ = 1.0       # below this a line is the load's own change, not the bounce
BOUNCE_MIN_PEAK = 4.0     # the line must stand this many times above the band's median
MOVING_M_S = 0.1          # the hoist moves (winds) above this speed
STOPPED_S = 0.25          # the counter stands this long: the hoist has stopped


# A hoist whose k, pressure noise or bounce is this far from the values NODE.json was built
# with reads its empty-cage pithead total about 0.1-0.15 % off (notes/accuracy-research.md,
# "Sensitivity" and "The transmitters' noise"); a re-fit of the same hoist repeats within
# about a third of these.
RECHECK_K_REL = 0.01       # k of any rope, relative
RECHECK_NOISE_REL = 0.03   # the pressure noise, relative, with the node's plays fixed
RECHECK_BOUNCE_HZ = 0.1    # the bounce
# With noise following (docs/model.md) the node scales its plays by the noise it measures
# itself: this far, the pithead total's mean moves by about 0.1 % (notes/accuracy-research.md, "The
# transmitters' noise": 0.07 % at 20 %, 0.13 % at 33 %). Beyond it the node flags its
# frames noise_changed (the same tolerance, layout.NOISE_TOL_Q10).
RECHECK_NOISE_FOLLOWED_REL = L.NOISE_TOL_Q10 / 1024


class ComplianceError(ValueError):
    """A recording from which k cannot be fitted; the message names the rope and why."""


@dataclass
class ComplianceFit:
    k_m_per_pa: list[float]      # per rope
    r: list[float]               # correlation of position and pressure
    span_pa: list[float]         # pressure range used (5th to 95th percentile)
    residual_m: list[float]      # rms of position about the line (noise and slow flows)
    pressure_noise_pa: float     # rms sample-to-sample noise of the pressure channels (median rope)
    displacement_noise_m: float  # the same of the displacement channels (worst rope)
    samples: int
    bounce_hz: float | None = None  # the bounce after the last arrival (None: not measured)
    used_fraction: float = 1.0      # share of the recording k was fitted on (outside strokes and creep)
    left_out_s: float = 0.0         # seconds left out (balancing strokes, creep)
    volume_ratio: float | None = None  # sum A x against sum A k p over the recording (1: consistent)
    warnings: list[str] = field(default_factory=list)
    method: str = "per-rope"        # "common": the ropes part, k_i = K / (n A_i) from the volume line
    common_m3_per_pa: float | None = None  # K = sum A_i k_i (the fitted common K when method is common)

    def as_dict(self) -> dict:
        return {"hydraulic_compliance_m_per_Pa": self.k_m_per_pa,
                "pressure_noise_Pa": self.pressure_noise_pa,
                "displacement_noise_m": self.displacement_noise_m, "bounce_hz": self.bounce_hz,
                "r": self.r,
                "pressure_span_Pa": self.span_pa, "residual_rms_m": self.residual_m,
                "samples": self.samples, "used_fraction": self.used_fraction,
                "left_out_s": self.left_out_s, "volume_ratio": self.volume_ratio,
                "method": self.method, "common_compliance_m3_per_Pa": self.common_m3_per_pa,
                "warnings": self.warnings}


def _scaled(ph: dict, records: np.ndarray, i: int):
    """Rope i's pressure (Pa), position (m), health mask, and the channels' steps (per count)."""
    n = int(ph["ropes"])
    pc = ph["pressure_channels"][i]
    dc = ph["displacement_channels"][i]
    cp = records[:, i].astype(float)
    cx = records[:, n + i].astype(float)
    plo, phi = namur_limits(pc["counts_4mA"], pc["counts_20mA"])
    xlo, xhi = namur_limits(dc["counts_lo"], dc["counts_hi"])
    ok = (cp >= plo) & (cp <= phi) & (cx >= xlo) & (cx <= xhi)
    lo, hi = pc["range_Pa"]
    p = lo + (cp - pc["counts_4mA"]) * (hi - lo) / (pc["counts_20mA"] - pc["counts_4mA"])
    ylo, yhi = dc["range_m"]
    x = ylo + (cx - dc["counts_lo"]) * (yhi - ylo) / (dc["counts_hi"] - dc["counts_lo"])
    p_step = abs(hi - lo) / abs(pc["counts_20mA"] - pc["counts_4mA"])
    x_step = abs(yhi - ylo) / abs(dc["counts_hi"] - dc["counts_lo"])
    return p, x, ok, p_step, x_step


def _blocks(v: np.ndarray, ok: np.ndarray, b: int) -> np.ndarray:
    """Means over blocks of b samples; NaN where any sample of the block is unhealthy."""
    m = len(v) // b
    out = v[: m * b].reshape(m, b).mean(axis=1)
    out[~ok[: m * b].reshape(m, b).all(axis=1)] = np.nan
    return out


def _departure(r: np.ndarray, h: int, block_s: float) -> np.ndarray:
    """Speed (m/s) at which r (block means) runs off: the mean of the h blocks after each
    block minus the mean of the h before it, over the time between them. NaN at the ends."""
    out = np.full(r.size, np.nan)
    if r.size < 2 * h + 1:
        return out
    c = np.concatenate([[0.0], np.cumsum(np.nan_to_num(r))])
    bad = np.concatenate([[0], np.cumsum(np.isnan(r))])
    b = np.arange(h, r.size - h)
    after = (c[b + 1 + h] - c[b + 1]) / h
    before = (c[b] - c[b - h]) / h
    valid = ((bad[b + 1 + h] - bad[b - h]) == 0)
    out[b] = np.where(valid, (after - before) / ((h + 1) * block_s), np.nan)
    return out


def fit(ph: dict, records: np.ndarray) -> ComplianceFit:
    """Fit k per rope from records[k, 2N+4] with the channel scaling of `physical` ph.

    k is fitted on the short-time changes of position and pressure (block means over
    BLOCK_S, their increments), leaving out the stretches where any rope's position runs
    off its line x = c + k p (a balancing stroke: one piston takes the common motion, the
    others stick; or a creep), so a wind with strokes gives each rope's compression."""
    n, fs = int(ph["ropes"]), float(ph["sample_hz"])
    b = max(1, int(round(BLOCK_S * fs)))
    block_s = b / fs
    chans, noise, x_noise = [], [], []
    for i in range(n):
        p, x, ok, p_step, x_step = _scaled(ph, records, i)
        if ok.sum() < 100:
            raise ComplianceError(f"rope {i + 1}: fewer than 100 samples with both channels healthy")
        span = float(np.percentile(p[ok], 95) - np.percentile(p[ok], 5))
        if span < MIN_SPAN_PA:
            raise ComplianceError(f"rope {i + 1}: the pressure changes by {span / 1e6:.3f} MPa "
                                  f"(5th to 95th percentile); k needs at least "
                                  f"{MIN_SPAN_PA / 1e6:.1f} MPa (record a loading or a wind)")
        noise.append(_white_noise(p[ok], p_step))
        x_noise.append(_white_noise(x[ok], x_step))
        chans.append((_blocks(p, ok, b), _blocks(x, ok, b)))
    P = np.array([c[0] for c in chans])
    X = np.array([c[1] for c in chans])
    var_p = [s ** 2 / b for s in noise]  # the pressure noise left in a block mean
    areas = _areas(ph, n)
    k = _first_k(P, X, areas, var_p)
    h = max(1, int(round(STROKE_SPAN_S / block_s)))
    pad = int(round(STROKE_PAD_S / block_s))
    piece = max(2, int(round(PIECE_S / block_s)))
    valid = ~np.isnan(P).any(axis=0) & ~np.isnan(X).any(axis=0)
    for _ in range(8):
        off = np.zeros(P.shape[1], bool)
        for i in range(n):
            s = _departure(X[i] - k[i] * P[i], h, block_s)
            # the rms of s from the channels' noise alone (two means of h blocks)
            sig = math.sqrt(2 * (x_noise[i] ** 2 + (k[i] * noise[i]) ** 2) / (h * b)) / ((h + 1) * block_s)
            off |= np.abs(np.nan_to_num(s)) > max(STROKE_SIGMAS * sig, STROKE_MIN_M_S)
        if pad:
            off = np.convolve(off, np.ones(2 * pad + 1), "same") > 0
        pieces = _pieces(valid & ~off, piece)
        k_new = np.array([_slope(P[i], X[i], pieces, var_p[i])[0] for i in range(n)])
        done = np.allclose(k_new, k, rtol=1e-4, atol=0)
        k = k_new
        if done:
            break
    used = float((valid & ~off).sum() / max(1, valid.sum()))
    left_out_s = float((valid & ~np.isnan(P).all(axis=0) & off).sum() * block_s)
    ks, rs, spans, res, failed = [], [], [], [], []
    for i in range(n):
        kk, se, pk, xk = _slope(P[i], X[i], pieces, var_p[i])
        kept = P[i][valid & ~off]
        span = float(np.percentile(kept, 95) - np.percentile(kept, 5)) if kept.size else 0.0
        r = float(np.corrcoef(pk, xk)[0, 1]) if pk.size > 2 and np.any(pk) and np.any(xk) else 0.0
        if span < MIN_SPAN_PA:
            failed.append((i, f"rope {i + 1}: position does not follow pressure: where it does (outside "
                              f"balancing strokes and creep, {used * 100:.0f} % of the recording), the pressure "
                              f"changes by {span / 1e6:.3f} MPa; k needs at least {MIN_SPAN_PA / 1e6:.1f} MPa"))
        elif kk <= 0 or r < MIN_R:
            failed.append((i, f"rope {i + 1}: position does not follow pressure (slope {kk:.3g} m/Pa, "
                              f"r = {r:.3f}; needs r >= {MIN_R}; on the {used * 100:.0f} % of the recording "
                              f"outside balancing strokes)"))
        elif se > MAX_REL_SE * kk:
            failed.append((i, f"rope {i + 1}: k = {kk:.4g} m/Pa is uncertain by {100 * se / kk:.1f} % "
                              f"(needs <= {100 * MAX_REL_SE:.0f} %)"))
        ks.append(float(kk))
        rs.append(r)
        spans.append(span)
        res.append(float(np.sqrt(np.mean((xk - kk * pk) ** 2))) if xk.size else 0.0)
    method, common, warnings = "per-rope", None, []
    if failed:
        common = _common(P, X, areas, valid, piece, noise, b)
        why = "; ".join(m for _, m in failed)
        if common["problem"]:
            raise ComplianceError(f"{why}; nor can the common compliance be measured: {common['problem']} "
                                  "(record a full wind with its loading and its stop at the landing)")
        method = "common"
        ks = [float(common["K"] / (n * a)) for a in areas]
        bad = ", ".join(str(i + 1) for i, _ in failed)
        warnings.append(
            f"per-rope k not measured: rope{'s' if len(failed) > 1 else ''} {bad} could not be fitted on "
            f"{'their' if len(failed) > 1 else 'its'} own ({why}): the ropes part through the wind (groove "
            f"creep, balancing strokes), so the pistons move together too little of it; k is the manifold's common compliance "
            f"K = sum A_i k_i = {common['K']:.4g} m^3/Pa (uncertain by {100 * common['rel_se']:.2f} %, "
            f"r = {common['r']:.3f}), split in equal volume shares k_i = K / ({n} A_i)")
    ratio, vwarn = _volume_check(ph, P, X, np.array(ks))
    return ComplianceFit(ks, rs, spans, res, float(np.median(noise)), max(x_noise), int(records.shape[0]),
                         bounce_hz(ph, records), used_fraction=used, left_out_s=left_out_s,
                         volume_ratio=ratio, warnings=warnings + vwarn, method=method,
                         common_m3_per_pa=(common["K"] if common else float(areas @ np.array(ks))))


def _common(P: np.ndarray, X: np.ndarray, areas: np.ndarray, valid: np.ndarray, piece: int,
            noise: list[float], b: int) -> dict:
    """The manifold's common compliance K (m^3/Pa): the slope of the pistons' oil volume
    sum A_i x_i on the median pressure over the whole recording, strokes and creep included
    (differential motions cancel in the sum), with an offset of its own per piece of at most
    PIECE_S (a slow drift of the oil's temperature moves the offset); `problem` says why it
    cannot be used (None: it can)."""
    pm = np.median(P, axis=0)
    v = areas @ np.nan_to_num(X)
    pieces = _pieces(valid, piece)
    n = P.shape[0]
    # the median of n channels' noise: about 0.55-0.71 of one channel's (docs/model.md)
    var_pm = (float(np.median(noise)) * (0.546 if n >= 4 else 0.707)) ** 2 / b
    K, se, pk, vk = _slope(pm, v, pieces, var_pm)
    span = float(np.percentile(pm[valid], 95) - np.percentile(pm[valid], 5)) if valid.any() else 0.0
    r = float(np.corrcoef(pk, vk)[0, 1]) if pk.size > 2 and np.any(pk) and np.any(vk) else 0.0
    rel = se / K if K > 0 else math.inf
    problem = None
    if span < MIN_SPAN_PA:
        problem = f"the median pressure changes by {span / 1e6:.3f} MPa, K needs at least {MIN_SPAN_PA / 1e6:.1f} MPa"
    elif K <= 0 or r < MIN_R:
        problem = (f"the pistons' oil volume sum A_i x_i does not follow the pressure (slope {K:.3g} m^3/Pa, "
                   f"r = {r:.3f}; needs r >= {MIN_R})")
    elif rel > MAX_REL_SE:
        problem = (f"K = {K:.4g} m^3/Pa is uncertain by {100 * rel:.1f} % (needs <= {100 * MAX_REL_SE:.0f} %)")
    return {"K": K, "rel_se": rel, "r": r, "span": span, "problem": problem}


def _pieces(keep: np.ndarray, most: int) -> list[np.ndarray]:
    """Index arrays of the runs of kept blocks, cut into pieces of at most `most` blocks."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(np.int8), [0]])))
    out = []
    for s, e in zip(edges[::2], edges[1::2]):
        for a in range(s, e, most):
            if min(a + most, e) - a >= 2:
                out.append(np.arange(a, min(a + most, e)))
    return out


def _slope(p: np.ndarray, x: np.ndarray, pieces: list[np.ndarray],
           var_p: float) -> tuple[float, float, np.ndarray, np.ndarray]:
    """(k, its standard error, p and x about each piece's mean, joined): least squares of
    position on pressure with an offset of its own in each piece (a stroke or a creep between
    pieces moves the offset, not k), the pressure noise's share of the sum of squares taken out."""
    if not pieces:
        return 0.0, math.inf, np.zeros(0), np.zeros(0)
    pk = np.concatenate([p[j] - p[j].mean() for j in pieces])
    xk = np.concatenate([x[j] - x[j].mean() for j in pieces])
    dof = pk.size - len(pieces)
    den = float(np.sum(pk * pk)) - dof * var_p
    if dof < 2 or den <= 0:
        return 0.0, math.inf, pk, xk
    kk = float(np.sum(pk * xk)) / den
    e = xk - kk * pk
    return kk, float(np.sqrt(np.sum(e * e) / (dof - 1) / den)), pk, xk


def _areas(ph: dict, n: int) -> np.ndarray:
    a = ph.get("cylinder_area_m2", 1.0)
    return np.asarray(a if isinstance(a, (list, tuple)) else [a] * n, float)


def _first_k(P: np.ndarray, X: np.ndarray, areas: np.ndarray, var_p: list[float]) -> np.ndarray:
    """A first k per rope, from 1 s increments where the pressure changes well beyond its
    noise, leaving out those where one piston takes most of the common motion (a stroke).
    The common motion is what the manifold's volume gives: sum A_i dx_i = K dp, K = sum A_i k_i
    the slope of sum A_i x_i on the median pressure over the whole recording (a stroke moves
    oil between the cylinders, not out of them). Each rope's k is then the dp^2-weighted median
    of dx/dp over the rest; the plain line of position on pressure where too few remain."""
    n = P.shape[0]
    lag = max(1, int(round(1.0 / BLOCK_S)))
    pm = np.median(P, axis=0)
    ok = ~np.isnan(P).any(axis=0) & ~np.isnan(X).any(axis=0)
    d_p = pm[lag:] - pm[:-lag]
    d_x = X[:, lag:] - X[:, :-lag]
    big = ~np.isnan(d_p) & ~np.isnan(d_x).any(axis=0) & (np.abs(d_p) > 20 * math.sqrt(max(var_p)))
    if n > 1 and ok.sum() > 10:
        v = areas @ X[:, ok]
        q = pm[ok] - pm[ok].mean()
        kv = float(np.sum((v - v.mean()) * q) / np.sum(q * q)) if np.any(q) else 0.0
        if kv > 0:
            share = areas[:, None] * d_x / (kv * np.where(big, d_p, 1.0))
            big &= share.max(axis=0) < STROKE_SHARE
    out = np.zeros(n)
    for i in range(n):
        if big.sum() < 10:
            sel = ~np.isnan(P[i]) & ~np.isnan(X[i])
            out[i] = float(np.polyfit(P[i][sel], X[i][sel], 1)[0])
            continue
        ratio, w = d_x[i][big] / d_p[big], d_p[big] ** 2
        o = np.argsort(ratio)
        c = np.cumsum(w[o])
        out[i] = float(ratio[o][np.searchsorted(c, 0.5 * c[-1])])
    return out


def _volume_check(ph: dict, P: np.ndarray, X: np.ndarray, k: np.ndarray) -> tuple[float | None, list[str]]:
    """The shared manifold keeps the oil's volume: sum A_i x_i moves by sum A_i k_i dp_i,
    strokes included. The slope of the one on the other over the whole recording (1 when
    the k fit), and a warning when it is off by more than MAX_VOLUME_DEV."""
    n = P.shape[0]
    a = _areas(ph, n)
    ok = ~np.isnan(P).any(axis=0) & ~np.isnan(X).any(axis=0)
    if n < 2 or ok.sum() < 10:
        return None, []
    v = a @ X[:, ok]
    q = (a * k) @ P[:, ok]
    q = q - q.mean()
    if not np.any(q):
        return None, []
    ratio = float(np.sum((v - v.mean()) * q) / np.sum(q * q))
    if abs(ratio - 1) <= MAX_VOLUME_DEV:
        return ratio, []
    return ratio, [f"the pistons' oil volume sum A_i x_i moves {ratio:.3f} times the compression "
                   f"sum A_i k_i p_i over the recording (expected 1 within {MAX_VOLUME_DEV * 100:g} %): "
                   "oil leaves or enters the circuit, or a piston creeps outside what was left out"]


def bounce_hz(ph: dict, records: np.ndarray) -> float | None:
    """The cage's bounce (Hz) at the recording's last arrival: the strongest spectral line
    of the median pressure (healthy channels) between BOUNCE_MIN_HZ and sample_hz/8 over
    BOUNCE_WINDOW_S after the hoist stops, the line fitted a parabola on a 16x zero-padded
    spectrum (linear trend removed, Hann window); None without such a stop, or where the
    line does not stand BOUNCE_MIN_PEAK times above the band's median."""
    n, fs = int(ph["ropes"]), float(ph["sample_hz"])
    try:
        m_per_pulse = float(ph["speed_m_per_pulse"])
    except (KeyError, TypeError, ValueError):
        return None
    counter = records[:, 2 * n + 2].astype(np.int64)
    step = (np.diff(counter) + 32768) % 65536 - 32768  # signed pulses per sample, mod 2**16
    win = max(1, int(round(0.1 * fs)))
    speed = np.abs(np.convolve(step, np.ones(win), "same")) * m_per_pulse * fs / win
    fast = np.flatnonzero(speed > MOVING_M_S)
    if not len(fast):
        return None
    still = int(round(STOPPED_S * fs))
    start = max(0, fast[-1] - win)  # the speed is a moving sum: its last pulses lie within it
    moved = np.flatnonzero(step[start:] != 0) + start
    # the stop: the first sample after the last pulse that is followed by STOPPED_S of none
    stop = None
    for a, b in zip(moved, np.append(moved[1:], len(step))):
        if b - a > still:
            stop = a + 1
            break
    n_win = int(round(BOUNCE_WINDOW_S * fs))
    if stop is None or stop + n_win > len(records):
        return None
    cols = []
    for i in range(n):
        pc = ph["pressure_channels"][i]
        lo, hi = namur_limits(pc["counts_4mA"], pc["counts_20mA"])
        c = records[stop:stop + n_win, i].astype(float)
        if np.all((c >= lo) & (c <= hi)):
            plo, phi = pc["range_Pa"]
            cols.append(plo + (c - pc["counts_4mA"]) * (phi - plo) / (pc["counts_20mA"] - pc["counts_4mA"]))
    if not cols:
        return None
    y = np.median(np.array(cols), axis=0)
    t = np.arange(n_win)
    y = (y - np.polyval(np.polyfit(t, y, 1), t)) * np.hanning(n_win)
    spec = np.abs(np.fft.rfft(y, 16 * n_win))
    f = np.fft.rfftfreq(16 * n_win, 1 / fs)
    band = np.flatnonzero((f >= BOUNCE_MIN_HZ) & (f <= fs / 8))
    k = band[np.argmax(spec[band])]
    if k in (band[0], band[-1]) or spec[k] < BOUNCE_MIN_PEAK * np.median(spec[band]):
        return None
    a, b, c = spec[k - 1], spec[k], spec[k + 1]
    return float(f[k] + 0.5 * (a - c) / (a - 2 * b + c) * (f[1] - f[0]))


def _white_noise(p: np.ndarray, step: float) -> float:
    """rms white noise of a sampled signal from its second differences (variance 6 sigma^2).

    Second differences cancel ramps and nearly cancel the slow swings of a wind (a
    0.3 MPa rope bounce at 1.5 Hz adds ~1 kPa at 200 Hz); the few large ones (steps,
    spikes) are dropped beyond 5 robust sigmas, and the rest give a plain rms, since a
    median of quantised counts moves in whole counts (one `step`, Pa per count).
    """
    d2 = np.diff(p, 2)
    dev = np.abs(d2 - np.median(d2))
    lim = 5 * max(1.4826 * float(np.median(dev)), step)
    return float(np.sqrt(np.mean(d2[dev <= lim] ** 2) / 6))


def recheck(ph: dict, res: ComplianceFit) -> list[tuple[str, bool]]:
    """(line, beyond its tolerance) per value NODE.json's `physical` took from an earlier fit:
    k (the rope farthest off; for a common fit, K = sum A_i k_i), the pressure noise, the
    bounce. Empty when it took none."""
    k_was = ph.get("hydraulic_compliance_m_per_Pa")
    if not isinstance(k_was, list) or not any(k_was) or len(k_was) != len(res.k_m_per_pa):
        return []
    out = []
    if res.method == "common":
        # equal volume shares, not each rope's k: what the fit measures is K = sum A_i k_i
        a = _areas(ph, len(k_was))
        now_k, was_k = float(a @ np.asarray(res.k_m_per_pa)), float(a @ np.asarray(k_was, float))
        rel_k = (now_k - was_k) / was_k if was_k else math.inf
        out.append((f"K {rel_k * 100:+.1f} %, the common compliance sum A_i k_i ({now_k:.4g} m^3/Pa, was "
                    f"{was_k:.4g}; tolerance {RECHECK_K_REL * 100:g} %; the ropes part, per-rope k not "
                    f"measured)", abs(rel_k) > RECHECK_K_REL))
    else:
        rel = [(now - was) / was if was else math.inf for now, was in zip(res.k_m_per_pa, k_was)]
        i = max(range(len(rel)), key=lambda j: abs(rel[j]))
        out.append((f"k {rel[i] * 100:+.1f} % on rope {i + 1}, the farthest ({res.k_m_per_pa[i]:.4g} m/Pa, "
                    f"was {k_was[i]:.4g}; tolerance {RECHECK_K_REL * 100:g} %)", abs(rel[i]) > RECHECK_K_REL))
    was = ph.get("pressure_noise_Pa")
    if isinstance(was, (int, float)) and was > 0:
        r = res.pressure_noise_pa / was - 1
        try:
            followed = physical_params(ph)["noise_shift"] > 0
        except (KeyError, TypeError, ValueError):
            followed = False
        tol, how = ((RECHECK_NOISE_FOLLOWED_REL, "; the node follows it") if followed
                    else (RECHECK_NOISE_REL, ", the node's plays fixed"))
        out.append((f"pressure noise {r * 100:+.1f} % ({res.pressure_noise_pa:.0f} Pa, was {was:.0f}; "
                    f"tolerance {tol * 100:g} %{how})", abs(r) > tol))
    was = ph.get("bounce_hz")
    if isinstance(was, (int, float)):
        if res.bounce_hz is None:
            out.append((f"bounce not measured in this recording (was {was:.2f} Hz)", False))
        else:
            d = res.bounce_hz - was
            out.append((f"bounce {d:+.2f} Hz ({res.bounce_hz:.2f} Hz, was {was:.2f}; "
                        f"tolerance {RECHECK_BOUNCE_HZ:g} Hz)", abs(d) > RECHECK_BOUNCE_HZ))
    return out


def add_arguments(p) -> None:
    p.add_argument("node_json", metavar="NODE.json", type=Path,
                   help="node.json (from `ropemon config`) whose physical section scales the channels")
    p.add_argument("rsens", metavar="SENSORS.rsens", type=Path,
                   help="recorded sensor stream with a loading or a wind (.rsens, docs/data-formats.md)")
    p.add_argument("--out", metavar="COMPLIANCE.json", type=Path,
                   help="also write the JSON here (name it in SITE.toml [compliance] file)")
    p.add_argument("--check", action="store_true",
                   help="exit 1 when k, the pressure noise or the bounce moved beyond its tolerance "
                        "since the fit NODE.json was built with")


def run(args) -> int:
    try:
        doc = files.read_json(args.node_json, "node.json", files.MAX_NODE_JSON, ComplianceError, allow_nan=True)
        ph = doc.get("physical") if isinstance(doc, dict) else None
        if not isinstance(ph, dict):
            raise ComplianceError(f"{args.node_json}: no physical section (a node.json from `ropemon config`)")
        from ropemon.station.physical import check_digest  # not changed since `ropemon config` wrote it
        check_digest(doc, args.node_json)
        try:
            ropes, hz, recs = read_rsens(args.rsens)
        except struct.error:
            raise ComplianceError(f"{args.rsens}: too short for a .rsens header") from None
        if (ropes, hz) != (ph.get("ropes"), ph.get("sample_hz")):
            raise ComplianceError(f"{args.rsens}: {ropes} ropes at {hz} Hz, {args.node_json} has "
                                  f"{ph.get('ropes')} at {ph.get('sample_hz')} Hz")
        try:
            res = fit(ph, recs)
        except (KeyError, TypeError, IndexError) as e:
            raise ComplianceError(f"{args.node_json}: physical.pressure_channels or "
                                  f"displacement_channels incomplete ({e!r})") from None
    except (OSError, ValueError) as e:
        print(f"ropemon fit-compliance: error: {e}", file=sys.stderr)
        return 2
    text = json.dumps(res.as_dict(), indent=1) + "\n"
    if args.out is not None:
        args.out.write_text(text)
    sys.stdout.write(text)
    lines = recheck(ph, res)
    for line, beyond in lines:
        print(f"ropemon fit-compliance: against {args.node_json.name}: {line}{': CHANGED' if beyond else ''}",
              file=sys.stderr)
    for w in res.warnings:
        print(f"ropemon fit-compliance: warning: {w}", file=sys.stderr)
    changed = any(beyond for _, beyond in lines)
    if changed:
        print(f"ropemon fit-compliance: {args.node_json.name} no longer fits this hoist: name this fit in "
              "SITE.toml [compliance], rebuild the config (ropemon config) and deploy it "
              "(docs/commissioning.md, \"Re-check in service\")", file=sys.stderr)
    return 1 if changed and args.check else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="ropemon fit-compliance", description=__doc__.split("\n\n")[0])
    add_arguments(ap)
    return run(ap.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
