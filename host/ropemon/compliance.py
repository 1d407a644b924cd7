"""Hydraulic compliance k (m/Pa) of each cylinder, fitted from a recorded sensor stream.

The oil in a cylinder, its hoses and the connecting assembly compresses with
pressure, so a piston moves by k dp when its pressure changes (docs/model.md,
"LuGre (noise-robust observer)"). Oil with entrained air makes k uncertain by tens of per cent
from the drawings, so the node's k is measured: a least-squares line of the
piston position on the pressure over a recording (a commissioning wind, or any
stream with loading and acceleration), on the node's own channel scaling. The
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
`[compliance]` table (ropemon.site), `ropemon config` puts it in `physical`.
"""
from __future__ import annotations

import argparse
import json
import math
import struct
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ropemon.nodeconfig import namur_limits, physical_params
from ropemon.protocol import L
from ropemon.reference import read_rsens

MIN_SPAN_PA = 0.3e6   # the pressure must change at least this much over the recording
MIN_R = 0.5           # correlation of position and pressure below which the fit is refused
MAX_REL_SE = 0.02     # standard error of k over k above which the fit is refused
BOUNCE_WINDOW_S = 4.0     # the arrival's bounce is looked for over this long after the stop
BOUNCE_MIN_HZ = 1.0       # below this a line is the load's own change, not the bounce
BOUNCE_MIN_PEAK = 4.0     # the line must stand this many times above the band's median
MOVING_M_S = 0.1          # the hoist moves (winds) above this speed
STOPPED_S = 0.25          # the counter stands this long: the hoist has stopped


# A hoist whose k, pressure noise or bounce is this far from the values NODE.json was built
# with reads its empty-cage pithead total about 0.1-0.15 % off (docs/accuracy.md,
# "Sensitivity" and "The transmitters' noise"); a re-fit of the same hoist repeats within
# about a third of these.
RECHECK_K_REL = 0.01       # k of any rope, relative
RECHECK_NOISE_REL = 0.03   # the pressure noise, relative, with the node's plays fixed
RECHECK_BOUNCE_HZ = 0.1    # the bounce
# With noise following (docs/model.md) the node scales its plays by the noise it measures
# itself: this far, the pithead total's mean moves by about 0.1 % (docs/accuracy.md, "The
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

    def as_dict(self) -> dict:
        return {"hydraulic_compliance_m_per_Pa": self.k_m_per_pa,
                "pressure_noise_Pa": self.pressure_noise_pa,
                "displacement_noise_m": self.displacement_noise_m, "bounce_hz": self.bounce_hz,
                "r": self.r,
                "pressure_span_Pa": self.span_pa, "residual_rms_m": self.residual_m,
                "samples": self.samples}


def fit(ph: dict, records: np.ndarray) -> ComplianceFit:
    """Fit k per rope from records[k, 2N+4] with the channel scaling of `physical` ph."""
    n = int(ph["ropes"])
    ks, rs, spans, res, noise, x_noise = [], [], [], [], [], []
    for i in range(n):
        pc = ph["pressure_channels"][i]
        dc = ph["displacement_channels"][i]
        cp = records[:, i].astype(float)
        cx = records[:, n + i].astype(float)
        plo, phi = namur_limits(pc["counts_4mA"], pc["counts_20mA"])
        xlo, xhi = namur_limits(dc["counts_lo"], dc["counts_hi"])
        ok = (cp >= plo) & (cp <= phi) & (cx >= xlo) & (cx <= xhi)
        if ok.sum() < 100:
            raise ComplianceError(f"rope {i + 1}: fewer than 100 samples with both channels healthy")
        lo, hi = pc["range_Pa"]
        p = lo + (cp[ok] - pc["counts_4mA"]) * (hi - lo) / (pc["counts_20mA"] - pc["counts_4mA"])
        ylo, yhi = dc["range_m"]
        x = ylo + (cx[ok] - dc["counts_lo"]) * (yhi - ylo) / (dc["counts_hi"] - dc["counts_lo"])
        span = float(np.percentile(p, 95) - np.percentile(p, 5))
        if span < MIN_SPAN_PA:
            raise ComplianceError(f"rope {i + 1}: the pressure changes by {span / 1e6:.3f} MPa "
                                  f"(5th to 95th percentile); k needs at least "
                                  f"{MIN_SPAN_PA / 1e6:.1f} MPa (record a loading or a wind)")
        slope, icpt = np.polyfit(p, x, 1)
        r = float(np.corrcoef(p, x)[0, 1])
        if slope <= 0 or r < MIN_R:
            raise ComplianceError(f"rope {i + 1}: position does not follow pressure (slope "
                                  f"{slope:.3g} m/Pa, r = {r:.3f}; needs r >= {MIN_R})")
        resid = x - (icpt + slope * p)
        se = float(np.sqrt(np.mean(resid ** 2) / (len(p) * np.var(p))))
        if se > MAX_REL_SE * slope:
            raise ComplianceError(f"rope {i + 1}: k = {slope:.4g} m/Pa is uncertain by {100 * se / slope:.1f} % "
                                  f"(needs <= {100 * MAX_REL_SE:.0f} %): record more pressure change")
        ks.append(float(slope))
        rs.append(r)
        spans.append(span)
        res.append(float(np.sqrt(np.mean((x - (icpt + slope * p)) ** 2))))
        noise.append(_white_noise(p, abs(hi - lo) / (pc["counts_20mA"] - pc["counts_4mA"])))
        x_noise.append(_white_noise(x, abs(yhi - ylo) / abs(dc["counts_hi"] - dc["counts_lo"])))
    return ComplianceFit(ks, rs, spans, res, float(np.median(noise)), max(x_noise), int(records.shape[0]),
                         bounce_hz(ph, records))


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
    k (the rope farthest off), the pressure noise, the bounce. Empty when it took none."""
    k_was = ph.get("hydraulic_compliance_m_per_Pa")
    if not isinstance(k_was, list) or not any(k_was) or len(k_was) != len(res.k_m_per_pa):
        return []
    out = []
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
        try:
            doc = json.loads(args.node_json.read_text())
        except json.JSONDecodeError as e:
            raise ComplianceError(f"{args.node_json}: not valid JSON: {e}") from None
        ph = doc.get("physical") if isinstance(doc, dict) else None
        if not isinstance(ph, dict):
            raise ComplianceError(f"{args.node_json}: no physical section (a node.json from `ropemon config`)")
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
