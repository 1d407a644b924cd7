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
                           [--site SITE.toml [--payload-kg KG]]

With --site the fit checks itself before it is accepted (`check_fit`): the node's float
reference (ropemon.commission.reference) runs over the recording with the fit and without it
(NODE.json's compensation as it is), and their totals at the rests whose load is known (the
empty cage and its tail ropes from SITE.toml, or with a weighed payload) are compared with that
load, raw p x A's beside them. A fit that puts the total at any such rest farther off than
without it by more than CHECK_TOL_FRAC of the load is refused (exit 2, nothing written, the
figures on stderr); by more than CHECK_MARGINAL_FRAC it is accepted with a warning. The
pistons' common motion against what the fit predicts from the pressure is reported too.

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
from ropemon.commission.site import G_M_S2
from ropemon.station import files
from ropemon.station.physical import as_physical

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
# The node's seal observer takes k only where the pistons follow their lines over at least this share of
# the recording (`ComplianceFit.observer`): elsewhere k p would move the seal state of a piston its
# seal holds. The recordings of the named scenarios keep their lines over all of it (1.00); the
# population's tuning hoists (balancing strokes, ropes parting, seals holding) over 0.02-0.41, and
# they read better without k in the observer (docs/accuracy.md, "What limits the accuracy").
OBSERVER_MIN_USED = 0.9
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

    @property
    def observer(self) -> bool:
        """Whether the node's seal observer takes this k (OBSERVER_MIN_USED); the oil balance takes it
        either way."""
        return self.used_fraction >= OBSERVER_MIN_USED

    def as_dict(self) -> dict:
        return {"hydraulic_compliance_m_per_Pa": self.k_m_per_pa, "observer_compliance": self.observer,
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
    warnings = warnings + vwarn
    if used < OBSERVER_MIN_USED:
        warnings.append(
            f"the pistons followed their lines of position on pressure over only {used * 100:.0f} % of the "
            f"recording (needs {OBSERVER_MIN_USED * 100:.0f} %: balancing strokes, ropes parting, seals holding "
            "their pistons): the node's seal observer runs without k (observer_compliance false), since k p "
            "would move the seal state of a piston its seal holds; the oil balance keeps k")
    return ComplianceFit(ks, rs, spans, res, float(np.median(noise)), max(x_noise), int(records.shape[0]),
                         bounce_hz(ph, records), used_fraction=used, left_out_s=left_out_s,
                         volume_ratio=ratio, warnings=warnings, method=method,
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
    k (the rope farthest off; for a common fit, K = sum A_i k_i), whether the seal observer
    takes k (a line only where this wind says otherwise), the pressure noise, the bounce. Empty
    when it took none."""
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
    # whether the seal observer takes k: the pistons' lines over this wind against the config's flag
    was_on = ph.get("observer_compliance", True) is not False
    if res.observer != was_on:
        now = "takes k" if res.observer else "runs without k"
        out.append((f"the pistons kept their lines over {res.used_fraction * 100:.0f} % of this wind (needs "
                    f"{OBSERVER_MIN_USED * 100:.0f} %): the seal observer now {now}, node.json's "
                    f"{'takes' if was_on else 'does not take'} it; rebuild the config from this fit", True))
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


# ---------------------------------------------------------------- the fit's own check

# physical keys a compliance fit gives (site.check_compliance) and those only a config with one keeps
FIT_KEYS = ("hydraulic_compliance_m_per_Pa", "observer_compliance", "pressure_noise_Pa", "displacement_noise_m",
            "bounce_hz")
WITH_FIT_KEYS = ("friction_play_sigmas", "noise_follow_s")
# A fit is refused when, at a rest of known load, it puts the node's total farther from that load than
# the node reads without it by more than this fraction of the load: what the channels cannot
# resolve at a rest (their noise alone spreads the empty-cage pithead total from wind to wind by
# a standard deviation of 0.13-0.19 % whatever reads them, docs/accuracy.md, "Transmitter
# noise"); three times the rest means' own noise (the transmitters' over the averaged samples,
# far below it) is added. Farther by more than CHECK_MARGINAL_FRAC: accepted with a warning
# (what one of the re-check tolerances is worth, docs/commissioning.md, "Re-check in service").
CHECK_TOL_FRAC = 0.003
CHECK_MARGINAL_FRAC = 0.001
CHECK_NOISE_SIGMAS = 3.0
REST_SPEED_M_S = 0.05     # the cage stands: slower than this
REST_MIN_S = 2.0          # a standstill at least this long with the pressure steady is a rest
REST_STEADY_PA_S = 50e3   # ... steady: the median pressure's 1 s mean moves slower than this (a load change is faster)
REST_AVG_MAX_S = 5.0      # a rest's figure: the mean over its second half, at most this long
KNOWN_MATCH_FRAC = 0.10   # a rest carries a known load when the node reads within this of it
MOTION_WARN_FRAC = 0.10   # the pistons' motion off the fitted compliance's by this much is warned
PAYLOAD_MAX_FRAC = 1.5    # --payload-kg: at most this times the site's rated payload


@dataclass
class KnownLoad:
    """What the static load at the cage's rope ends is at a rest (from SITE.toml [hoist]):
    the empty cage, the tail ropes hanging from it to their loop at the shaft bottom and,
    when weighed, a payload."""

    cage_kg: float
    tail_ropes: int
    tail_kg_per_m: float
    shaft_m: float
    payload_kg: float | None = None

    def load_n(self, depth_m: float, payload_kg: float = 0.0) -> float:
        tail_m = max(self.shaft_m - depth_m, 0.0)
        return (self.cage_kg + payload_kg + self.tail_ropes * self.tail_kg_per_m * tail_m) * G_M_S2


def known_load(site_path: Path, payload_kg: float | None, ph: dict) -> KnownLoad:
    """The known load from SITE.toml, checked against the node.json it built (its cage weight);
    `payload_kg` a weighed payload (> 0, at most PAYLOAD_MAX_FRAC x the rated payload)."""
    from ropemon.commission.site import SiteError, in_file, load_site

    try:
        h = load_site(site_path).hoist
    except SiteError as e:
        raise ComplianceError(str(in_file(e, site_path))) from None
    was = ph.get("conveyance_weight_N")
    if isinstance(was, (int, float)) and abs(h.cage_mass_kg * G_M_S2 - was) > 1e-6 * max(1.0, abs(was)):
        raise ComplianceError(f"{site_path}: hoist.cage_mass_kg = {h.cage_mass_kg:g} kg weighs "
                              f"{h.cage_mass_kg * G_M_S2:.0f} N, the node.json's physical.conveyance_weight_N is "
                              f"{was:.0f} N: not the site the config was built from")
    if payload_kg is not None:
        top = PAYLOAD_MAX_FRAC * h.rated_payload_kg
        if not (math.isfinite(payload_kg) and 0 < payload_kg <= top):
            raise ComplianceError(f"--payload-kg: must be > 0 and at most {top:g} kg ({PAYLOAD_MAX_FRAC:g} x "
                                  f"hoist.rated_payload_kg), got {payload_kg:g}")
    return KnownLoad(h.cage_mass_kg, h.tail_ropes, h.tail_rope_kg_per_m, h.shaft_depth_m, payload_kg)


def with_fit(ph: dict, res: "ComplianceFit | None") -> dict:
    """`physical` ph with this fit's compliance in place of any it had (None: without any)."""
    from ropemon.commission.site import SiteError, check_compliance

    out = {k: v for k, v in ph.items() if k not in FIT_KEYS + WITH_FIT_KEYS}
    if res is None:
        return out
    try:
        out.update(check_compliance(res.as_dict(), int(ph["ropes"]), "the fit"))
    except SiteError as e:
        raise ComplianceError(str(e)) from None
    out.update({k: ph[k] for k in WITH_FIT_KEYS if k in ph})
    return out


def has_compliance(ph: dict) -> bool:
    """Whether `physical` ph gives the node's seal observer a compliance (`Physical.has_compliance`)."""
    return as_physical(ph).has_compliance


def rests(ph: dict, records: np.ndarray) -> list[tuple[int, int, float]]:
    """(first, end) samples averaged and the depth (m) of each rest of the recording: the cage
    standing (its net travel over 1 s below REST_SPEED_M_S) and the median pressure steady (its 1 s mean moving
    slower than REST_STEADY_PA_S) for at least REST_MIN_S; the mean over the second half, at
    most REST_AVG_MAX_S, ending half a second before the stretch does (the arrival's bounce and
    a load change settled, the next not begun). The depth counts from
    physical.start_depth_m, where the node starts (the Hall marks' snapping is not applied)."""
    n, fs = int(ph["ropes"]), float(ph["sample_hz"])
    m = records.shape[0]
    counter = records[:, 2 * n + 2].astype(np.int64)
    step = np.concatenate([[0], (np.diff(counter) + 32768) % 65536 - 32768])
    depth = float(ph.get("start_depth_m", 0.0)) + np.cumsum(step) * float(ph["speed_m_per_pulse"])
    # standing: the net travel over 1 s slower than REST_SPEED_M_S (the ropes' stretch and bounce
    # after a load change move the cage by centimetres, back and forth)
    win = max(1, int(round(fs)))
    moving = np.abs(np.convolve(step, np.ones(win), "same")) * float(ph["speed_m_per_pulse"]) * fs / win \
        > REST_SPEED_M_S
    cols = []
    for i in range(n):
        p, _, ok, _, _ = _scaled(ph, records, i)
        cols.append(np.where(ok, p, np.nan))
    with np.errstate(all="ignore"):
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            pm = np.nanmedian(np.array(cols), axis=0)
    w = max(1, int(round(fs)))
    valid = np.isfinite(pm)
    c = np.concatenate([[0.0], np.cumsum(np.nan_to_num(pm))])
    rate = np.full(m, np.inf)
    if m > 2 * w:
        j = np.arange(w, m - w + 1)
        rate[j] = np.abs((c[j + w] - c[j]) - (c[j] - c[j - w])) / w * fs / w  # 1 s means 1 s apart
    steady = ~moving & valid & (rate < REST_STEADY_PA_S)
    out = []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], steady.astype(np.int8), [0]])))
    for s, e in zip(edges[::2], edges[1::2]):
        if e - s < REST_MIN_S * fs:
            continue
        e -= w // 2  # the 1 s means see a load change coming half a second early
        a = max((s + e) // 2, e - int(REST_AVG_MAX_S * fs))
        out.append((int(a), int(e), float(np.median(depth[a:e]))))
    return out


@dataclass
class RestFigure:
    """A rest of known load: the node's total there with this fit, without it (NODE.json's
    compensation as it is), with no compliance at all (when NODE.json has one), and raw p x A."""

    t_s: float
    depth_m: float
    what: str
    known_n: float
    with_n: float
    without_n: float
    raw_n: float
    none_n: float | None = None

    def err(self, v: float) -> float:
        return (v - self.known_n) / self.known_n

    @property
    def harm(self) -> float:
        """How much farther from the known load the fit puts the total than it is without it."""
        return abs(self.err(self.with_n)) - abs(self.err(self.without_n))

    def figure(self, name: str, v: float) -> str:
        return f"{name} {self.err(v) * 100:+.2f} % ({(v - self.known_n) / 1e3:+.2f} kN)"

    def line(self) -> str:
        s = (f"rest at {self.t_s:.1f} s, depth {self.depth_m:.1f} m, {self.what} {self.known_n / 1e3:.2f} kN: "
             f"{self.figure('with the fit', self.with_n)}, {self.figure('without', self.without_n)}")
        if self.none_n is not None:
            s += f", {self.figure('with no compliance', self.none_n)}"
        return s + f", {self.figure('raw p x A', self.raw_n)}"

    def as_dict(self) -> dict:
        d = {"t_s": self.t_s, "depth_m": self.depth_m, "load": self.what, "known_N": self.known_n,
             "with_N": self.with_n, "without_N": self.without_n, "raw_N": self.raw_n,
             "with_err": self.err(self.with_n), "without_err": self.err(self.without_n),
             "raw_err": self.err(self.raw_n)}
        if self.none_n is not None:
            d.update(none_N=self.none_n, none_err=self.err(self.none_n))
        return d


@dataclass
class FitCheck:
    """The fit checked where the load is known (`check_fit`)."""

    rests: list[RestFigure]
    tol_frac: float                 # the refusal's tolerance, of the known load
    motion_rms_m: float | None      # the pistons' common motion off the fit's prediction (rms, m)
    motion_frac: float | None       # ... over the predicted motion's rms
    rests_found: int = 0            # rests in the recording (known load or not)
    unknown: list[tuple[float, float, float]] = field(default_factory=list)  # (t_s, depth_m, N read) not compared

    @property
    def worst(self) -> RestFigure | None:
        return max(self.rests, key=lambda r: r.harm) if self.rests else None

    @property
    def verdict(self) -> str:
        """'unchecked' (no rest of known load), 'worse' (refused), 'marginal' (warned), 'ok'."""
        w = self.worst
        if w is None:
            return "unchecked"
        if w.harm > self.tol_frac:
            return "worse"
        return "marginal" if w.harm > CHECK_MARGINAL_FRAC else "ok"

    def configured_harm(self) -> RestFigure | None:
        """The rest where NODE.json's own compliance puts the total farthest beyond what no
        compliance reads, when that is beyond the tolerance (None: within, or none to compare)."""
        rs = [r for r in self.rests if r.none_n is not None]
        if not rs:
            return None
        r = max(rs, key=lambda r: abs(r.err(r.without_n)) - abs(r.err(r.none_n)))
        return r if abs(r.err(r.without_n)) - abs(r.err(r.none_n)) > self.tol_frac else None

    def as_dict(self) -> dict:
        w = self.worst
        return {"verdict": self.verdict, "tolerance_frac": self.tol_frac,
                "worst_harm_frac": None if w is None else w.harm, "rests_found": self.rests_found,
                "rests": [r.as_dict() for r in self.rests],
                "not_compared": [{"t_s": t, "depth_m": d, "without_N": v if math.isfinite(v) else None}
                                 for t, d, v in self.unknown],
                "motion_residual_rms_m": self.motion_rms_m, "motion_residual_frac": self.motion_frac}


def _totals(ph: dict, records: np.ndarray, spans) -> tuple[list[float], list[float]]:
    """The node's compensated total and raw p x A (N) over each span, by the float reference,
    without the do-no-harm limit: at a rest that limit would hide what the fit does to the model."""
    from ropemon.commission.reference import compensate

    c = compensate(dict(ph, hold_play_sigmas=0.0), records)
    with np.errstate(all="ignore"):
        comp = [float(np.nanmean(c.tension_n[a:b].sum(axis=1))) for a, b, _ in spans]
        raw = [float(np.mean(c.raw_tension_n[a:b].sum(axis=1))) for a, b, _ in spans]
    return comp, raw


def motion_residual(ph: dict, records: np.ndarray, res: "ComplianceFit") -> tuple[float | None, float | None]:
    """The pistons' common motion sum A_i x_i against what the fit predicts from the pressure,
    sum A_i k_i p_i, over the whole recording (balancing strokes and groove creep cancel in the
    sum), each PIECE_S piece about its own mean (a slow drift of the oil's temperature moves
    the offset): the rms of the difference over sum A_i (m of mean piston travel), and that over
    the predicted motion's rms. None when the recording has no such piece."""
    n, fs = int(ph["ropes"]), float(ph["sample_hz"])
    b = max(1, int(round(BLOCK_S * fs)))
    P, X = [], []
    for i in range(n):
        p, x, ok, _, _ = _scaled(ph, records, i)
        P.append(_blocks(p, ok, b))
        X.append(_blocks(x, ok, b))
    P, X = np.array(P), np.array(X)
    a = _areas(ph, n)
    valid = ~np.isnan(P).any(axis=0) & ~np.isnan(X).any(axis=0)
    pieces = _pieces(valid, max(2, int(round(PIECE_S / (b / fs)))))
    if not pieces:
        return None, None
    v = a @ np.nan_to_num(X) / a.sum()
    q = (a * np.asarray(res.k_m_per_pa)) @ np.nan_to_num(P) / a.sum()
    dv = np.concatenate([v[j] - v[j].mean() for j in pieces])
    dq = np.concatenate([q[j] - q[j].mean() for j in pieces])
    rms = float(np.sqrt(np.mean((dv - dq) ** 2)))
    pred = float(np.sqrt(np.mean(dq ** 2)))
    return rms, (rms / pred if pred > 0 else None)


def check_fit(ph: dict, records: np.ndarray, res: "ComplianceFit", load: KnownLoad) -> FitCheck:
    """Run the node's float reference (ropemon.commission.reference) over the recording with this
    fit and without it (NODE.json's compensation as it is; and with no compliance at all when
    NODE.json has one), and compare their totals at the rests whose load is known: the empty
    cage, or the cage with the weighed payload, whichever the node reads within
    KNOWN_MATCH_FRAC of (without the fit); a rest near neither carries an unknown load and is
    not compared. Also the pistons' motion against the fit's prediction (`motion_residual`)."""
    spans = rests(ph, records)
    without, raw = _totals(ph, records, spans)
    known = []
    for (a, b, depth), tot in zip(spans, without):
        cands = [("empty cage", load.load_n(depth))]
        if load.payload_kg:
            cands.append((f"cage with {load.payload_kg:g} kg", load.load_n(depth, load.payload_kg)))
        what, n_known = min(cands, key=lambda c: abs(tot - c[1]))
        known.append((what, n_known) if math.isfinite(tot) and abs(tot - n_known) <= KNOWN_MATCH_FRAC * n_known
                     else None)
    keep = [j for j, k in enumerate(known) if k is not None]
    fs = float(ph["sample_hz"])
    figs: list[RestFigure] = []
    tol = CHECK_TOL_FRAC
    if keep:
        sel = [spans[j] for j in keep]
        withv, _ = _totals(with_fit(ph, res), records, sel)
        nonev = _totals(with_fit(ph, None), records, sel)[0] if has_compliance(ph) else [None] * len(sel)
        for j, w, nn in zip(keep, withv, nonev):
            a, b, depth = spans[j]
            figs.append(RestFigure(a / fs + (b - a) / (2 * fs), depth, known[j][0], known[j][1], w, without[j],
                                   raw[j], nn))
        # the rest means' own noise: the transmitters' over the averaged samples, summed over the ropes
        a_mean = float(np.mean(_areas(ph, int(ph["ropes"]))))
        shortest = min(b - a for a, b, _ in sel)
        noise_n = res.pressure_noise_pa * a_mean * math.sqrt(int(ph["ropes"]) / shortest)
        tol = CHECK_TOL_FRAC + CHECK_NOISE_SIGMAS * noise_n / min(f.known_n for f in figs)
    rms, frac = motion_residual(ph, records, res)
    unknown = [((a + b) / (2 * fs), depth, without[j]) for j, (a, b, depth) in enumerate(spans) if known[j] is None]
    return FitCheck(figs, tol, rms, frac, len(spans), unknown)


def add_arguments(p) -> None:
    p.add_argument("node_json", metavar="NODE.json", type=Path,
                   help="node.json (from `ropemon config`) whose physical section scales the channels")
    p.add_argument("rsens", metavar="SENSORS.rsens", type=Path,
                   help="recorded sensor stream with a loading or a wind (.rsens, docs/data-formats.md)")
    p.add_argument("--out", metavar="COMPLIANCE.json", type=Path,
                   help="also write the JSON here (name it in SITE.toml [compliance] file)")
    p.add_argument("--check", action="store_true",
                   help="exit 1 when k, the pressure noise or the bounce moved beyond its tolerance "
                        "since the fit NODE.json was built with, or when NODE.json's own compliance makes "
                        "the total at the rests of known load worse than none (with --site)")
    p.add_argument("--site", metavar="SITE.toml", type=Path,
                   help="the site NODE.json was built from: its cage mass, tail ropes and shaft depth give "
                        "the known load at the recording's rests, where the fit is checked before it is "
                        "accepted (the node's float reference with and without it)")
    p.add_argument("--payload-kg", metavar="KG", type=float,
                   help="a weighed payload the cage carried at some rests of the recording (with --site)")


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
        load = None if args.site is None else known_load(args.site, args.payload_kg, ph)
        if args.site is None and args.payload_kg is not None:
            raise ComplianceError("--payload-kg: needs --site (the cage and tail ropes it is added to)")
        try:
            res = fit(ph, recs)
        except (KeyError, TypeError, IndexError) as e:
            raise ComplianceError(f"{args.node_json}: physical.pressure_channels or "
                                  f"displacement_channels incomplete ({e!r})") from None
    except (OSError, ValueError) as e:
        print(f"ropemon fit-compliance: error: {e}", file=sys.stderr)
        return 2
    chk = None
    if args.site is not None:
        try:
            chk = check_fit(ph, recs, res, load)
        except (KeyError, TypeError, IndexError) as e:
            print(f"ropemon fit-compliance: error: {args.node_json}: cannot run the node's reference on it "
                  f"({e!r})", file=sys.stderr)
            return 2
        except ValueError as e:
            print(f"ropemon fit-compliance: error: {e}", file=sys.stderr)
            return 2
        for r in chk.rests:
            print(f"ropemon fit-compliance: check: {r.line()}", file=sys.stderr)
        for t, depth, v in chk.unknown:
            print(f"ropemon fit-compliance: check: rest at {t:.1f} s, depth {depth:.1f} m, load not known: reads "
                  f"{v / 1e3:.2f} kN without the fit, not within {KNOWN_MATCH_FRAC * 100:g} % of a known load; "
                  "not compared", file=sys.stderr)
        w = chk.worst
        if chk.verdict == "worse":
            print(f"ropemon fit-compliance: error: the fitted compliance makes the node's total worse where the load "
                  f"is known: at the rest at {w.t_s:.1f} s (depth {w.depth_m:.1f} m, {w.what} "
                  f"{w.known_n / 1e3:.2f} kN) {w.figure('it reads', w.with_n)} with the fit, "
                  f"{w.figure('', w.without_n).strip()} without it ({args.node_json.name} as it is), "
                  f"{w.figure('raw p x A', w.raw_n)}: {w.harm * 100:.2f} % of the load farther off, beyond the "
                  f"tolerance {chk.tol_frac * 100:.2f} %; nothing written (check the displacement transmitters' "
                  "scaling and mounting and the oil circuit, then record another commissioning wind; "
                  "docs/commissioning.md, \"The fit's own check\")", file=sys.stderr)
            return 2
    text = json.dumps(res.as_dict() if chk is None else dict(res.as_dict(), check=chk.as_dict()), indent=1) + "\n"
    if args.out is not None:
        args.out.write_text(text)
    sys.stdout.write(text)
    lines = recheck(ph, res)
    if chk is not None:
        bad = chk.configured_harm()
        if bad is not None:
            lines.append((f"its own compliance puts the total at the rest at {bad.t_s:.1f} s ({bad.what} "
                          f"{bad.known_n / 1e3:.2f} kN) {(abs(bad.err(bad.without_n)) - abs(bad.err(bad.none_n))) * 100:.2f} "
                          f"% of the load farther off than no compliance ({bad.figure('it reads', bad.without_n)}, "
                          f"{bad.figure('with none', bad.none_n)}; tolerance {chk.tol_frac * 100:.2f} %)", True))
    for line, beyond in lines:
        print(f"ropemon fit-compliance: against {args.node_json.name}: {line}{': CHANGED' if beyond else ''}",
              file=sys.stderr)
    for w in res.warnings:
        print(f"ropemon fit-compliance: warning: {w}", file=sys.stderr)
    if chk is None:
        print("ropemon fit-compliance: warning: the fit is not checked against a known load (give --site "
              "SITE.toml: the node's total at the recording's rests with and without it)", file=sys.stderr)
    else:
        for w in check_warnings(chk):
            print(f"ropemon fit-compliance: warning: {w}", file=sys.stderr)
    changed = any(beyond for _, beyond in lines)
    if changed:
        print(f"ropemon fit-compliance: {args.node_json.name} no longer fits this hoist: name this fit in "
              "SITE.toml [compliance], rebuild the config (ropemon config) and deploy it "
              "(docs/commissioning.md, \"Re-check in service\")", file=sys.stderr)
    return 1 if changed and args.check else 0


def check_warnings(chk: FitCheck) -> list[str]:
    """What the check warns of (the fit still accepted): no rest of known load, a fit within the
    tolerance but no better than without it, the pistons' motion off the fit's prediction."""
    out = []
    w = chk.worst
    if chk.verdict == "unchecked":
        out.append(f"the fit is not checked: none of the recording's {chk.rests_found} rests reads within "
                   f"{KNOWN_MATCH_FRAC * 100:g} % of a known load (the empty cage, or --payload-kg); record the "
                   "commissioning wind with a rest of the empty cage")
    elif chk.verdict == "marginal":
        out.append(f"the fit puts the total at the rest at {w.t_s:.1f} s {w.harm * 100:.2f} % of the load farther off "
                   f"than without it (within the tolerance {chk.tol_frac * 100:.2f} %): accepted, but it does "
                   "not improve the reading there")
    if chk.motion_frac is not None and chk.motion_frac > MOTION_WARN_FRAC:
        out.append(f"the pistons' common motion departs from what the fitted compliance predicts from the pressure "
                   f"by {chk.motion_rms_m * 1e6:.1f} um rms, {chk.motion_frac * 100:.0f} % of the predicted motion "
                   f"(warned beyond {MOTION_WARN_FRAC * 100:g} %)")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="ropemon fit-compliance", description=__doc__.split("\n\n")[0])
    add_arguments(ap)
    return run(ap.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
