"""`ropemon fit-friction DATA.csv`: LuGre seal-friction parameters from friction test-bed records.

Method (docs/commissioning.md, "Friction calibration"):
1. Split the record into constant-velocity runs; the second half of each run
   (the bristles have settled) gives one steady-state point (v, F, p).
2. Group the runs into pressure levels; per level fit the steady-state Stribeck
   curve F = sgn(v) (Fc + (Fs - Fc) exp(-(v/vs)^2)) + sigma2 v to both directions
   with scipy.optimize.least_squares (the seal model: ropemon.commission.seal).
3. Fit Fs, Fc, vs, sigma2 each linearly against pressure (slope, intercept, r,
   95 % confidence intervals).
4. sigma0, sigma1 from the slow stretches (pre-sliding reversals): the LuGre
   state is simulated from the last steady run with the fitted lines; sigma0
   minimises the force residual (sigma1 enters linearly and is solved exactly).
   Besides, the reversals' initial slope dF/dx (`fit_initial_slope`), which needs
   no long slow stretch and no LuGre: it gives sigma0 (sigma1 default) unless the
   reversals start as LuGre's do and the simulation identified sigma0.
   Without usable pre-sliding data: documented defaults, with a warning.
5. The standstill after a run: a LuGre seal keeps its bristle force when the
   piston stops (z does not change at v = 0); a seal without pre-sliding (a
   Coulomb-Stribeck law) releases it. The force held over the run's sliding
   force is `standstill_hold_ratio` (median over the standstills); the node's
   model needs one near 1, and `ropemon config` refuses a seal below
   MIN_STANDSTILL_HOLD (site.check_friction).
6. The residual (`residual`): the fitted LuGre re-run over the whole record
   (measured velocity and pressure, z from rest at each pressure level) against
   the measured force, per level, for the sliding and the pre-sliding samples
   separately, in N and as a fraction of the level's Fs. Beyond
   RESIDUAL_MAX_SLIDING or RESIDUAL_MAX_PRESLIDING (RMS over Fs) the seal is one
   the node's model cannot represent: a warning, and `representable` false.
7. The check (`check_bed`, the command only): the node's float reference over the record with
   the fit and raw p x A, against the bed's force, held out by level where 4 or more levels
   allow it; a fit that reads it worse than raw p x A beyond BED_CHECK_NOISE_SIGMAS times the
   bed's force noise is refused, nothing written (docs/commissioning.md, "fit-friction's check").

Every refusal (bad columns, NaN, one pressure level, one direction, too few
points, no convergence) raises FitError with the reason; the command exits 1.
"""
from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ropemon.commission.seal import LINES, bristle_force, g, line_at, lines_at, steady_force
from ropemon.station import files

COLUMNS = ("time_s", "pressure_MPa", "velocity_m_s", "friction_N")

MIN_RECORDS = 50
MIN_LEVELS = 3              # a line through two points has no confidence interval
MIN_POINTS_PER_DIRECTION = 4
MIN_RUN_S = 0.5             # shortest constant-velocity run used
MIN_RUN_TRAVEL_M = 1e-3     # and its least travel: slow reversals must not pass for runs
RUN_TOLERANCE = 0.05        # a run's velocity stays within 5 % of its median (plus the noise floor)
MIN_R2 = 0.95              # share of the friction variance a level's Stribeck fit must explain
LEVEL_GAP_MPA = 0.5         # runs whose pressures differ by more belong to different levels
MIN_PRESLIDING_S = 2.0

# Defaults when the record has no usable pre-sliding part (docs/commissioning.md):
# sigma0 = Fs(p_mid) / PRESLIDING_DISPLACEMENT_M: elastomer seals deflect ~0.1 mm before they slide;
# sigma1 = sigma0 * DAMPING_TIME_S.
DEFAULT_PRESLIDING_DISPLACEMENT_M = 1e-4
DEFAULT_DAMPING_TIME_S = 1e-3
PRESLIDING_SUBSTEPS = 4
PRESLIDING_MAX_REL_ERR = 0.25  # sigma0 counts as identified when its standard error is below 25 %
# The initial slope after a reversal (fit_initial_slope): a line over the first part of each swing
INITIAL_SLOPE_FORCE_FRACTION = 0.1  # until the force has changed by 10 % of 2 Fs(p)
SHAPE_FORCE_FRACTION = 0.25        # and its shape (elastic line or LuGre's exponential) until 25 %
MIN_TURN_SAMPLES = 6
MIN_TURNS = 4
MIN_TURN_GAP_S = 0.3       # a reversal, not a stop and a new start
SIGMA1_MAX_REL_ERR = 0.5       # sigma1 (weakly seen by any bed: it acts only while bristles deflect)

MIN_STANDSTILL_S = 0.3        # a standstill this long right after a run shows what the seal holds
STANDSTILL_AFTER_RUN_S = 1.0   # (the ramp down from the run lies between them)
MIN_STANDSTILL_HOLD = 0.5      # a LuGre seal holds ~0.9 of its sliding force; below this it is not one

# The residual's limits, worst level's RMS over its Fs(p) (docs/commissioning.md, "How well the
# model fits"). The simulated bed: a LuGre seal with the bed's instrument noise gives 1.2-1.4 %
# in both parts (six seeds), with 3 % scatter of the seal's lines about straight lines up to
# 4.4 % sliding and 4.8 % pre-sliding (eight seeds); a Coulomb-Stribeck seal 63-70 % and 30-32 %,
# the plant's example elasto-plastic seal 3.6 % and 13 %, its Maxwell-slip seal 2.9 % and 7.3 %.
RESIDUAL_MAX_SLIDING = 0.05
RESIDUAL_MAX_PRESLIDING = 0.10

PARAMS = LINES
UNITS = {"Fs": "N", "Fc": "N", "vs": "m/s", "sigma2": "N s/m"}


class FitError(ValueError):
    """Test-bed data that cannot give a trustworthy fit; the message says why."""


@dataclass
class Level:
    pressure_MPa: float
    v: np.ndarray           # steady-state points, one per run
    F: np.ndarray
    params: dict[str, float] = field(default_factory=dict)
    stderr: dict[str, float] = field(default_factory=dict)
    rms_N: float = 0.0


@dataclass
class Record:
    t: np.ndarray
    p: np.ndarray
    v: np.ndarray
    F: np.ndarray


# ---------------------------------------------------------------- reading


def read_csv(path: Path | str) -> Record:
    """The four columns of a test-bed CSV (header required, extra columns ignored)."""
    path = Path(path)
    # a regular file of at most files.MAX_CSV, UTF-8 (spreadsheet exports often start with a BOM),
    # fields of at most files.MAX_CSV_FIELD characters, at most files.MAX_CSV_ROWS rows
    text = files.read_text(path, "test-bed CSV", files.MAX_CSV, FitError, encoding="utf-8-sig")
    reader = files.csv_rows(text, path, "test-bed CSV", FitError)
    header = next(reader, (0, None))[1]
    if header is None:
        raise FitError(f"{path}: empty file")
    header = [h.strip() for h in header]
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise FitError(f"{path}: missing column(s) {', '.join(missing)} in the header "
                       f"(need {', '.join(COLUMNS)}; got {', '.join(header)})")
    idx = [header.index(c) for c in COLUMNS]
    rows = []
    for line_no, row in reader:
        if not row or all(not c.strip() for c in row):
            continue
        try:
            vals = [float(row[i]) for i in idx]
        except (ValueError, IndexError):
            raise FitError(f"{path}:{line_no}: not a number in {', '.join(COLUMNS)}: {row!r}") from None
        for name, x in zip(COLUMNS, vals):
            if not math.isfinite(x):
                raise FitError(f"{path}:{line_no}: {name} is {x} (NaN or infinite values are not accepted)")
        rows.append(vals)
    if len(rows) < MIN_RECORDS:
        raise FitError(f"{path}: too few records ({len(rows)}; need at least {MIN_RECORDS})")
    a = np.asarray(rows)
    if np.any(np.diff(a[:, 0]) <= 0):
        i = int(np.argmax(np.diff(a[:, 0]) <= 0)) + 3
        raise FitError(f"{path}:{i}: time_s must increase strictly")
    return Record(t=a[:, 0], p=a[:, 1], v=a[:, 2], F=a[:, 3])


# ---------------------------------------------------------------- runs and levels


def _median_filter(x: np.ndarray, k: int) -> np.ndarray:
    from scipy.ndimage import median_filter
    return median_filter(x, size=k, mode="nearest")


def _sample_period(rec: Record) -> float:
    return float(np.median(np.diff(rec.t)))


def _velocity_smooth(rec: Record) -> tuple[np.ndarray, float]:
    """Median-filtered velocity and its noise floor (robust sd of the sample-to-sample change)."""
    dt = _sample_period(rec)
    k = max(3, int(round(0.05 / dt)) | 1)
    vm = _median_filter(rec.v, k)
    d = np.diff(vm)
    floor = 1.4826 * float(np.median(np.abs(d - np.median(d)))) + 1e-12
    return vm, floor


def find_runs(rec: Record) -> list[tuple[int, int]]:
    """Constant-velocity runs as (start, stop) index ranges of their settled second half."""
    dt = _sample_period(rec)
    vm, floor = _velocity_smooth(rec)
    band = 4 * floor
    gaps = np.flatnonzero(np.diff(rec.t) > 5 * dt) + 1
    moving = np.abs(vm) > band
    sign = np.where(moving, np.sign(vm), 0)
    # boundaries: sign changes (incl. to/from rest) and time gaps
    cut = set(np.flatnonzero(np.diff(sign) != 0) + 1) | set(gaps.tolist())
    edges = [0] + sorted(cut) + [len(vm)]
    runs = []
    for a, b in zip(edges, edges[1:]):
        if sign[a] == 0 or b - a < 3:
            continue
        med = float(np.median(vm[a:b]))
        ok = np.abs(vm[a:b] - med) <= RUN_TOLERANCE * abs(med) + band
        # longest contiguous stretch near the median: the plateau between the ramps
        best, start = (0, 0), None
        for i, flag in enumerate(np.append(ok, False)):
            if flag and start is None:
                start = i
            elif not flag and start is not None:
                if i - start > best[1] - best[0]:
                    best = (start, i)
                start = None
        s, e = a + best[0], a + best[1]
        if (e - s) * dt < MIN_RUN_S or abs(med) * (rec.t[e - 1] - rec.t[s]) < MIN_RUN_TRAVEL_M:
            continue
        half = s + (e - s) // 2
        runs.append((int(half), int(e)))
    return runs


def steady_levels(rec: Record, runs: list[tuple[int, int]]) -> list[Level]:
    """Steady-state (v, F) points of the runs, grouped by pressure level (ascending)."""
    if not runs:
        raise FitError("no constant-velocity runs found (each speed must be held for at least "
                       f"{MIN_RUN_S:g} s and {MIN_RUN_TRAVEL_M * 1e3:g} mm; see the test procedure)")
    pts = np.array([(np.median(rec.p[a:b]), np.median(rec.v[a:b]), np.median(rec.F[a:b])) for a, b in runs])
    if not np.any(pts[:, 1] < 0):
        raise FitError("no negative velocities: the procedure needs runs in both directions")
    if not np.any(pts[:, 1] > 0):
        raise FitError("no positive velocities: the procedure needs runs in both directions")
    order = np.argsort(pts[:, 0])
    pts = pts[order]
    groups: list[list[np.ndarray]] = [[pts[0]]]
    for row in pts[1:]:
        prev = groups[-1][-1][0]
        if row[0] - prev > max(LEVEL_GAP_MPA, 0.1 * abs(prev)):
            groups.append([row])
        else:
            groups[-1].append(row)
    levels = []
    for group in groups:
        a = np.array(group)
        levels.append(Level(pressure_MPa=float(np.median(a[:, 0])), v=a[:, 1], F=a[:, 2]))
    if len(levels) < MIN_LEVELS:
        found = ", ".join(f"{lv.pressure_MPa:.2f}" for lv in levels)
        raise FitError(f"{len(levels)} pressure level(s) found ({found} MPa); need at least {MIN_LEVELS} "
                       "to fit each parameter against pressure")
    for lv in levels:
        for name, mask in (("negative", lv.v < 0), ("positive", lv.v > 0)):
            n = int(np.sum(mask))
            if n < MIN_POINTS_PER_DIRECTION:
                raise FitError(f"pressure level {lv.pressure_MPa:.2f} MPa: too few points: {n} {name}-velocity "
                               f"runs, need at least {MIN_POINTS_PER_DIRECTION} per direction")
    return levels


# ---------------------------------------------------------------- Stribeck fit per level


def fit_level(lv: Level) -> None:
    """Fit Fs, Fc, vs, sigma2 of one pressure level to both directions (fills lv.params)."""
    from scipy.optimize import least_squares

    av, aF = np.abs(lv.v), np.abs(lv.F)
    order = np.argsort(av)
    fast = order[len(order) // 2:]
    slope, icpt = np.polyfit(av[fast], aF[fast], 1)
    x0 = np.array([max(aF[order[:2]].mean(), 1.0), max(icpt, 0.5 * aF.min(), 1.0),
                   float(np.median(av)) / 2, max(slope, 0.0)])
    lo = np.array([0.0, 0.0, av.min() / 100, 0.0])
    hi = np.array([np.inf, np.inf, av.max() * 10, np.inf])
    x0 = np.clip(x0, lo + 1e-12, hi / 2)

    def resid(x: np.ndarray) -> np.ndarray:
        return steady_force(lv.v, *x) - lv.F

    res = least_squares(resid, x0, bounds=(lo, hi), x_scale=np.maximum(np.abs(x0), 1e-6), method="trf")
    where = f"pressure level {lv.pressure_MPa:.2f} MPa"
    if not res.success or res.status <= 0:
        raise FitError(f"{where}: the Stribeck fit did not converge ({res.message})")
    Fs, Fc, vs, s2 = res.x
    if not np.all(np.isfinite(res.x)):
        raise FitError(f"{where}: the Stribeck fit did not converge (non-finite parameters)")
    if Fc <= 0 or Fs <= 0:
        raise FitError(f"{where}: the Stribeck fit did not converge to positive friction (Fs={Fs:g}, Fc={Fc:g} N)")
    vmin, vmax = float(av.min()), float(av.max())
    if not vmin / 2 <= vs <= vmax:
        raise FitError(f"{where}: fitted Stribeck velocity {vs:g} m/s is outside the measured speeds "
                       f"{vmin:g}..{vmax:g} m/s: the runs must cover speeds well below and above it")
    n, k = len(lv.v), 4
    rms = float(np.sqrt(np.mean(res.fun ** 2)))
    r2 = 1.0 - float(np.sum(res.fun ** 2)) / max(float(np.sum((lv.F - lv.F.mean()) ** 2)), 1e-300)
    if r2 < MIN_R2:
        raise FitError(f"{where}: the Stribeck curve does not describe the data (R^2 = {r2:.3f} < {MIN_R2}; "
                       f"residual {rms:.0f} N): check the force signal and its sign convention")
    stderr = [float("nan")] * 4
    if n > k:
        s2_res = float(np.sum(res.fun ** 2)) / (n - k)
        try:
            cov = np.linalg.inv(res.jac.T @ res.jac) * s2_res
            stderr = [float(math.sqrt(max(c, 0.0))) for c in np.diag(cov)]
        except np.linalg.LinAlgError:
            raise FitError(f"{where}: the Stribeck fit is degenerate (parameters not identifiable)") from None
    lv.params = {"Fs": float(Fs), "Fc": float(Fc), "vs": float(vs), "sigma2": float(s2)}
    lv.stderr = dict(zip(("Fs", "Fc", "vs", "sigma2"), stderr))
    lv.rms_N = rms


# ---------------------------------------------------------------- lines against pressure


def fit_lines(levels: list[Level]) -> dict[str, dict[str, Any]]:
    from scipy import stats

    p = np.array([lv.pressure_MPa for lv in levels])
    n = len(levels)
    tq = float(stats.t.ppf(0.975, n - 2))
    out = {}
    for key in PARAMS:
        y = np.array([lv.params[key] for lv in levels])
        r = stats.linregress(p, y)
        out[key] = {
            "slope": float(r.slope),
            "intercept": float(r.intercept),
            "r": float(r.rvalue) if np.ptp(y) > 0 else 0.0,
            "slope_ci95": [float(r.slope - tq * r.stderr), float(r.slope + tq * r.stderr)],
            "intercept_ci95": [float(r.intercept - tq * r.intercept_stderr),
                               float(r.intercept + tq * r.intercept_stderr)],
            "stderr_at_mean": float(np.sqrt(np.sum((y - r.intercept - r.slope * p) ** 2) / (n - 2) / n)),
            "unit": UNITS[key],
            "slope_unit": f"{UNITS[key]}/MPa",
        }
    return out


# ---------------------------------------------------------------- pre-sliding


def _g_of(lines: dict[str, Any], vel: np.ndarray, pres: np.ndarray) -> np.ndarray:
    """g(v) by the fitted lines, kept positive where a line runs out of its range."""
    fs, fc, vs, _ = lines_at(lines, pres)
    return np.maximum(g(vel, fs, fc, np.maximum(vs, 1e-9)), 1e-9)


@dataclass
class Presliding:
    segments: list[tuple[int, int, int, bool]]   # (sim_start, score_start, stop, starts_at_rest)


def find_presliding(rec: Record, lines: dict[str, Any], runs: list[tuple[int, int]]) -> Presliding:
    """Slow stretches (|v| well below the Stribeck velocity, no constant-velocity run) showing pre-sliding.

    Each is simulated from the end of the last steady run before it (where the
    bristle state is known: z = sgn(v) g(v)/sigma0), or from rest at the start
    of its pressure level.
    """
    dt = _sample_period(rec)
    vm, floor = _velocity_smooth(rec)
    p_hi = float(np.max(rec.p))
    vs_min = float(min(line_at(lines, "vs", 0.0), line_at(lines, "vs", p_hi)))
    slow = np.abs(vm) < max(vs_min / 4, 4 * floor)
    gaps = set((np.flatnonzero(np.diff(rec.t) > 5 * dt) + 1).tolist())
    level_starts = sorted({0} | gaps)
    run_ends = sorted(b for _, b in runs)
    segs = []
    i, n = 0, len(vm)
    while i < n:
        if not slow[i]:
            i += 1
            continue
        j = i
        while j < n and slow[j] and (j == i or j not in gaps):
            j += 1
        # constant-velocity runs are steady-state data, not pre-sliding: a stretch holding one is skipped
        holds_run = any(a < j and b > i for a, b in runs)
        if (j - i) * dt >= MIN_PRESLIDING_S and np.ptp(vm[i:j]) > 8 * floor and not holds_run:
            level_start = max(s for s in level_starts if s <= i)
            prior = [e for e in run_ends if level_start < e <= i]
            segs.append((prior[-1] - 1, i, j, False) if prior else (level_start, i, j, True))
        i = j
    return Presliding(segs)


def fit_presliding(rec: Record, lines: dict[str, Any], runs: list[tuple[int, int]],
                   sigma0: float | None = None) -> dict[str, float] | None:
    """sigma0, sigma1 (with relative standard errors and the residual) from the slow stretches, or None.

    With `sigma0` given only sigma1 is solved for (used to see how the steady-state
    lines' own errors move it).
    """
    from scipy.optimize import minimize_scalar

    ps = find_presliding(rec, lines, runs)
    if not ps.segments:
        return None
    p = _median_filter(rec.p, 5)
    dts = np.diff(rec.t, prepend=rec.t[0] - _sample_period(rec))
    # Velocity varies within a sample (ramps, sinusoids): step with the mid-sample velocity.
    # Measurement noise on v would make the simulated bristles creep at rest: use the
    # median-filtered velocity with a deadband at its noise level.
    vm, floor = _velocity_smooth(rec)
    v = np.where(np.abs(vm) < 2 * floor, 0.0, vm)
    # Velocity varies within a sample (ramps, sinusoids): integrate SUBSTEPS steps per
    # sample with the velocity interpolated linearly from the previous sample.
    n_sub = PRESLIDING_SUBSTEPS
    v_prev = np.concatenate([v[:1], v[:-1]])
    frac = (np.arange(n_sub) + 0.5) / n_sub
    v_sub = v_prev[:, None] + (v - v_prev)[:, None] * frac[None, :]      # (samples, substeps)

    gv = _g_of(lines, v, p)
    g_sub = _g_of(lines, v_sub, p[:, None])
    w_ss = (np.sign(v_sub) * g_sub).ravel()
    rate = (np.abs(v_sub) / g_sub * (dts / n_sub)[:, None]).ravel()   # decay exponent per unit sigma0
    y_all = rec.F - line_at(lines, "sigma2", p) * rec.v   # F - sigma2 v = sigma0 z + sigma1 dz/dt

    def trajectories(sigma0: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per stretch: (sigma0 z, dz/dt, F - sigma2 v) at the scored samples."""
        out = []
        for a, s, e, at_rest in ps.segments:
            # from rest at a level start, else steady sliding at the end of the last run
            w0 = 0.0 if at_rest else math.copysign(gv[a], v[a])
            sl = slice(a * n_sub, e * n_sub)
            w = bristle_force(w_ss[sl], np.exp(-sigma0 * rate[sl]), w0)[n_sub - 1::n_sub][s - a:]
            out.append((w, v[s:e] - np.abs(v[s:e]) * w / gv[s:e], y_all[s:e]))
        return out

    def solve(log_s0: float, skip: int = -1) -> tuple[float, float]:
        """(residual sum of squares, sigma1) at sigma0 = 10**log_s0; sigma1 enters linearly."""
        parts = [t for i, t in enumerate(trajectories(10 ** log_s0)) if i != skip]
        w, zd, y = (np.concatenate(c) for c in zip(*parts))
        r0 = y - w
        den = float(zd @ zd)
        s1 = max(float(zd @ r0) / den, 0.0) if den > 0 else 0.0
        r = r0 - s1 * zd
        return float(r @ r), s1

    if sigma0 is not None:
        return {"sigma0": sigma0, "sigma1": solve(math.log10(sigma0))[1]}
    opt = minimize_scalar(lambda x: solve(x)[0], bounds=(4.0, 11.0), method="bounded",
                          options={"xatol": 1e-4})
    x = float(opt.x)
    sse, s1 = solve(x)
    n = sum(e - s for _, s, e, _ in ps.segments)
    s2_res = sse / max(n - 2, 1)
    # standard error of log10(sigma0) from the curvature of the residual sum of squares
    h = 0.02
    curv = (solve(x + h)[0] - 2 * sse + solve(x - h)[0]) / (h * h)
    rel0 = math.log(10) * math.sqrt(2 * s2_res / curv) if curv > 0 else math.inf
    if x <= 4.01 or x >= 10.99:
        rel0 = math.inf  # at a bound: not identified
    # sigma1 is seen only through the small force of the deflecting bristles, where model and
    # instrument errors are systematic: its error comes from a leave-one-stretch-out jackknife.
    k = len(ps.segments)
    if k >= 3 and s1 > 0:
        loo = np.array([solve(x, skip=i)[1] for i in range(k)])
        rel1 = math.sqrt((k - 1) / k * float(np.sum((loo - loo.mean()) ** 2))) / s1
    else:
        rel1 = math.inf
    return {"sigma0": 10 ** x, "sigma1": s1, "sigma0_rel_err": rel0, "sigma1_rel_err": rel1,
            "rms_N": math.sqrt(sse / n), "samples": n, "stretches": k}


def find_turns(rec: Record, lines: dict[str, Any], runs: list[tuple[int, int]]) -> list[int]:
    """Slow reversals: the sample where the velocity turns (its smallest |v|) between a stretch
    of one sign and one of the other, both outside the constant-velocity runs, with the piston
    at rest at most MIN_TURN_GAP_S and slower than vs/4 around the turn, no run within
    STANDSTILL_AFTER_RUN_S (the ramps between the runs are not the procedure's reversals). Unlike
    `find_presliding` it needs no long slow stretch: a reversal faster than vs/4 away from its
    turns still gives its turns."""
    dt = _sample_period(rec)
    vm, floor = _velocity_smooth(rec)
    band = 4 * floor
    p = _median_filter(rec.p, 5)
    slow = np.abs(vm) < np.maximum(line_at(lines, "vs", p) / 4, band)
    sign = np.where(np.abs(vm) > band, np.sign(vm), 0.0)
    in_run = np.zeros(len(vm), bool)
    for a, b in runs:
        in_run[a:b] = True
    gaps = np.flatnonzero(np.diff(rec.t) > 5 * dt) + 1
    moving = np.flatnonzero(sign != 0)
    near = int(round(STANDSTILL_AFTER_RUN_S / dt))
    turns = []
    for i, j in zip(moving[:-1], moving[1:]):   # consecutive moving samples i < j
        if sign[i] == sign[j] or (j - i - 1) * dt > MIN_TURN_GAP_S or np.any((gaps > i) & (gaps <= j)):
            continue
        k = i + int(np.argmin(np.abs(vm[i:j + 1])))
        if not (slow[i] and slow[j]) or in_run[max(k - near, 0):k + near + 1].any():
            continue   # the ramp between two runs is no pre-sliding reversal of the procedure
        turns.append(k)
    return turns


def fit_initial_slope(rec: Record, lines: dict[str, Any], runs: list[tuple[int, int]],
                      force: np.ndarray | None = None) -> dict[str, float] | None:
    """The initial stiffness dF/dx after the slow reversals (`find_turns`), or None.

    Per turn: the displacement from the turn (trapezoidal integral of the measured velocity),
    F - sigma2(p) v against it, a Theil-Sen line over the samples from the turn until the force
    has changed by INITIAL_SLOPE_FORCE_FRACTION of 2 Fs(p) (the whole pre-sliding swing), while
    the piston keeps its direction and stays slower than vs/4. The stiffness is the median over
    the turns with MIN_TURN_SAMPLES or more samples; its relative error the median's standard
    error (1.2533 x the robust sd over sqrt(n)). `force` replaces the measured force.

    The shape of the start, up to SHAPE_FORCE_FRACTION of 2 Fs(p): an elastic line (Maxwell-slip
    before its first element slips, elasto-plastic up to its break-away) or LuGre's exponential
    2 Fs (1 - exp(-S x / (2 Fs))) after a reversal from sliding, whose initial slope S is
    2 sigma0 (dz/dt = v (1 - sigma0 z sgn(v) / g) = 2 v at z = -g/sigma0). `lugre_shape`: the
    exponential fits the turns better (sum of squares over all turns, each with a free offset);
    `lugre_sigma0` the median of S/2.
    """
    from scipy.optimize import minimize_scalar
    from scipy.stats import theilslopes

    turns = find_turns(rec, lines, runs)
    if not turns:
        return None
    F = rec.F if force is None else force
    p = _median_filter(rec.p, 5)
    vm, floor = _velocity_smooth(rec)
    y = F - line_at(lines, "sigma2", p) * rec.v
    ys = _median_filter(y, 3)
    dts = np.diff(rec.t)
    limit = np.abs(vm) < np.maximum(line_at(lines, "vs", p) / 4, 4 * floor)
    slopes, spans, sse_line, sse_exp, lugre_s0 = [], [], 0.0, 0.0, []
    n = len(F)
    dt = _sample_period(rec)
    for k in turns:
        # direction after the turn: the first clearly moving sample's
        after = np.flatnonzero(np.abs(vm[k:min(k + 200, n)]) > 4 * floor)
        if not after.size:
            continue
        sg = float(np.sign(vm[k + after[0]]))
        fs = float(line_at(lines, "Fs", p[k]))
        y0 = float(np.median(ys[max(k - 1, 0):k + 2]))
        need, need_shape = (f * 2 * fs for f in (INITIAL_SLOPE_FORCE_FRACTION, SHAPE_FORCE_FRACTION))
        e = k + 1
        while e < n and limit[e] and vm[e] * sg > -4 * floor and abs(ys[e] - y0) < need_shape and \
                rec.t[e] - rec.t[e - 1] <= 5 * dt:
            e += 1
        if e >= n or abs(ys[e] - y0) < need_shape:
            continue   # the swing ran out (slow and one-way) before the force changed enough
        e1 = k + 1 + int(np.argmax(np.abs(ys[k + 1:e + 1] - y0) >= need))
        if e1 - k < MIN_TURN_SAMPLES:
            continue   # too few samples on the initial slope
        x = sg * np.concatenate([[0.0], np.cumsum(0.5 * (rec.v[k:e - 1] + rec.v[k + 1:e]) * dts[k:e - 1])])
        yy = sg * y[k:e]
        if np.ptp(x[:e1 - k]) <= 0:
            continue
        s = float(theilslopes(yy[:e1 - k], x[:e1 - k])[0])
        if s <= 0:
            continue
        slopes.append(s)
        spans.append(float(np.ptp(x[:e1 - k])))
        # the same start as LuGre's after a reversal from sliding: 2 Fs (1 - exp(-S x / (2 Fs))),
        # initial slope S = 2 sigma0; against the elastic line (both with a free offset)
        r_line = yy - np.polyval(np.polyfit(x, yy, 1), x)   # least squares, as the exponential's
        sse_line += float(r_line @ r_line)

        def sse_of(log_s: float) -> float:
            c = 2 * fs * (1 - np.exp(-(10 ** log_s) * x / (2 * fs)))
            r = yy - c
            r = r - r.mean()
            return float(r @ r)

        o = minimize_scalar(sse_of, bounds=(math.log10(s) - 1.5, math.log10(s) + 1), method="bounded",
                            options={"xatol": 1e-4})
        sse_exp += float(o.fun)
        lugre_s0.append(10 ** float(o.x) / 2)
    if len(slopes) < MIN_TURNS:
        return None
    a = np.array(slopes)
    med = float(np.median(a))
    sd = 1.4826 * float(np.median(np.abs(a - med)))
    return {"sigma0": med, "sigma0_rel_err": 1.2533 * sd / math.sqrt(len(a)) / med, "turns": len(a),
            "turn_scatter": sd / med, "span_m": float(np.median(spans)),
            "lugre_shape": sse_exp < sse_line, "sse_ratio": sse_exp / max(sse_line, 1e-300),
            "lugre_sigma0": float(np.median(lugre_s0))}


# ---------------------------------------------------------------- residual of the fitted model


def model_force(rec: Record, doc: dict[str, Any]) -> np.ndarray:
    """The fitted LuGre (`doc`: its lines, sigma0, sigma1) run over the record: the force it
    predicts at every sample. The state starts from rest (z = 0) at the record's start and
    after every time gap (a new pressure level); the velocity is the median-filtered one with
    a deadband at its noise floor and the pressure median-filtered, as in the pre-sliding fit;
    PRESLIDING_SUBSTEPS steps per sample with the exact update."""
    s0, s1 = float(doc["sigma0"]), float(doc["sigma1"])
    dt = _sample_period(rec)
    p = _median_filter(rec.p, 5)
    vm, floor = _velocity_smooth(rec)
    v = np.where(np.abs(vm) < 2 * floor, 0.0, vm)
    dts = np.diff(rec.t, prepend=rec.t[0] - dt)
    n_sub = PRESLIDING_SUBSTEPS
    starts = np.zeros(len(v), bool)
    starts[0] = True
    starts[1:] = np.diff(rec.t) > 5 * dt
    dts[starts] = dt          # the state starts at that sample: no step across a gap
    v_prev = np.concatenate([v[:1], v[:-1]])
    v_prev[starts] = 0.0
    frac = (np.arange(n_sub) + 0.5) / n_sub
    v_sub = v_prev[:, None] + (v - v_prev)[:, None] * frac[None, :]

    g_sub = _g_of(doc, v_sub, p[:, None])
    w_ss = np.sign(v_sub) * g_sub
    decay = np.exp(-s0 * np.abs(v_sub) / g_sub * (dts / n_sub)[:, None])
    w = np.empty(len(v))
    edges = list(np.flatnonzero(starts)) + [len(v)]
    for a, b in zip(edges, edges[1:]):
        w[a:b] = bristle_force(w_ss[a:b].ravel(), decay[a:b].ravel(), 0.0)[n_sub - 1::n_sub]
    zdot = v - np.abs(v) * w / _g_of(doc, v, p)
    return w + s1 * zdot + line_at(doc, "sigma2", p) * v


def _part(r: np.ndarray, ref_N: float) -> dict[str, Any] | None:
    if not r.size:
        return None
    rms, mx = float(np.sqrt(np.mean(r * r))), float(np.max(np.abs(r)))
    return {"samples": int(r.size), "rms_N": rms, "max_N": mx, "rms_frac": rms / ref_N, "max_frac": mx / ref_N}


def residual(rec: Record, doc: dict[str, Any]) -> dict[str, Any]:
    """How well the fitted LuGre reproduces the bed's own record (the `residual` section).

    Per pressure level of the fit: the measured force minus `model_force`, over the
    sliding samples (|v| at or above a quarter of the level's vs, or its noise band) and
    the pre-sliding ones (slower: reversals, standstills), RMS and largest, in N and
    over Fs at the level's pressure. A sample belongs to the level nearest its pressure
    (within LEVEL_GAP_MPA or 10 %). The worst level's RMS fractions are compared with
    RESIDUAL_MAX_SLIDING and RESIDUAL_MAX_PRESLIDING (`representable`).
    """
    r = rec.F - model_force(rec, doc)
    vm, floor = _velocity_smooth(rec)
    p = _median_filter(rec.p, 5)
    lv_p = np.array([lv["pressure_MPa"] for lv in doc["levels"]])
    nearest = np.argmin(np.abs(p[:, None] - lv_p[None, :]), axis=1)
    near = np.abs(p - lv_p[nearest]) <= np.maximum(LEVEL_GAP_MPA, 0.1 * np.abs(lv_p[nearest]))
    slow = np.abs(vm) < np.maximum(line_at(doc, "vs", p) / 4, 4 * floor)
    levels = []
    for i, pl in enumerate(lv_p.tolist()):
        fs = float(line_at(doc, "Fs", pl))
        here = near & (nearest == i)
        levels.append({"pressure_MPa": pl, "Fs_N": fs,
                       "sliding": _part(r[here & ~slow], fs), "presliding": _part(r[here & slow], fs)})

    def worst(part: str) -> float | None:
        vals = [lv[part]["rms_frac"] for lv in levels if lv[part] is not None]
        return max(vals) if vals else None

    ws, wp = worst("sliding"), worst("presliding")
    return {"levels": levels, "sliding_rms_frac": ws, "presliding_rms_frac": wp,
            "max_sliding_rms_frac": RESIDUAL_MAX_SLIDING, "max_presliding_rms_frac": RESIDUAL_MAX_PRESLIDING,
            "representable": (ws is None or ws <= RESIDUAL_MAX_SLIDING)
            and (wp is None or wp <= RESIDUAL_MAX_PRESLIDING)}


def residual_warning(res: dict[str, Any]) -> str | None:
    """The warning for a seal beyond the residual thresholds, or None."""
    if res["representable"]:
        return None
    bad = []
    for part, lim in (("sliding", RESIDUAL_MAX_SLIDING), ("presliding", RESIDUAL_MAX_PRESLIDING)):
        over = [lv for lv in res["levels"] if lv[part] is not None and lv[part]["rms_frac"] > lim]
        if over:
            lv = max(over, key=lambda x: x[part]["rms_frac"])
            bad.append(f"{part.replace('presliding', 'pre-sliding')} RMS {lv[part]['rms_frac'] * 100:.1f} % of Fs "
                       f"at {lv['pressure_MPa']:.1f} MPa ({lv[part]['rms_N']:.0f} N; limit {lim * 100:.0f} %)")
    return ("residual: the fitted LuGre does not reproduce this seal's force on its own record: "
            + "; ".join(bad) + ". The node's friction model cannot represent this seal: its compensated "
            "tensions carry an error of this size")


def residual_table(res: dict[str, Any]) -> str:
    """The residual per level as printed by the command."""
    rows = ["residual of the fitted model on the record (RMS / max, N and % of Fs(p)):",
            f"  {'MPa':>6} {'Fs N':>7}  {'sliding':^27}  {'pre-sliding':^27}"]

    def cell(c: dict[str, Any] | None) -> str:
        if c is None:
            return f"{'-':^27}"
        return (f"{c['rms_N']:6.0f} /{c['max_N']:6.0f} N {c['rms_frac'] * 100:4.1f}/"
                f"{c['max_frac'] * 100:4.1f} %")

    for lv in res["levels"]:
        rows.append(f"  {lv['pressure_MPa']:6.2f} {lv['Fs_N']:7.0f}  {cell(lv['sliding'])}  {cell(lv['presliding'])}")
    verdict = "within" if res["representable"] else "BEYOND"
    rows.append(f"  worst RMS: sliding {_pct(res['sliding_rms_frac'])}, pre-sliding "
                f"{_pct(res['presliding_rms_frac'])}: {verdict} the limits "
                f"({RESIDUAL_MAX_SLIDING * 100:.0f} %, {RESIDUAL_MAX_PRESLIDING * 100:.0f} %)")
    return "\n".join(rows)


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{x * 100:.1f} %"


# ---------------------------------------------------------------- the whole fit


def standstill_holds(rec: Record, runs: list[tuple[int, int]]) -> list[dict[str, float]]:
    """Each standstill (velocity within the noise band for MIN_STANDSTILL_S or longer)
    that follows a run within STANDSTILL_AFTER_RUN_S: its pressure, the run's sliding
    force, the force held over the standstill's second half, and their ratio."""
    dt = _sample_period(rec)
    vm, floor = _velocity_smooth(rec)
    still = np.abs(vm) <= 4 * floor
    edges = np.flatnonzero(np.diff(np.concatenate(([0], still.astype(np.int8), [0]))))
    gaps = np.flatnonzero(np.diff(rec.t) > 5 * dt) + 1
    out = []
    for i, j in zip(edges[::2], edges[1::2]):
        j = int(min([j] + [g for g in gaps if i < g < j]))  # a stretch ends at a time gap
        before = [r for r in runs if r[1] <= i and rec.t[i] - rec.t[r[1] - 1] <= STANDSTILL_AFTER_RUN_S]
        if (j - i) * dt < MIN_STANDSTILL_S or not before:
            continue
        a, b = before[-1]
        sliding = float(np.median(rec.F[a:b]))
        held = float(np.median(rec.F[i + (j - i) // 2:j]))
        if sliding:
            out.append({"pressure_MPa": float(np.median(rec.p[i:j])), "sliding_N": sliding, "held_N": held,
                        "ratio": held / sliding})
    return out


def fit(rec: Record, source: str = "") -> tuple[dict[str, Any], list[Level], list[str]]:
    """Fit a test-bed record; returns (friction.json document, per-level fits, warnings)."""
    warnings: list[str] = []
    runs = find_runs(rec)
    levels = steady_levels(rec, runs)
    for lv in levels:
        fit_level(lv)
    lines = fit_lines(levels)
    p_lo, p_hi = levels[0].pressure_MPa, levels[-1].pressure_MPa
    for key in PARAMS:
        for p in (p_lo, p_hi):
            if key != "sigma2" and line_at(lines, key, p) <= 0:
                raise FitError(f"{key}: the line against pressure is not positive at {p:.2f} MPa "
                               f"({line_at(lines, key, p):g} {UNITS[key]}); the data do not support a linear fit")
    for key in PARAMS:
        r = lines[key]["r"]
        if abs(r) < 0.8:
            warnings.append(f"{key}: weak linear dependence on pressure (r = {r:.3f})")
    pre = fit_presliding(rec, lines, runs)
    if pre is not None and pre["sigma1"] > 0 and math.isfinite(pre["sigma1_rel_err"]):
        # sigma1's force is tens of newtons on kilonewtons of bristle force: an error of the
        # steady-state lines shifts it. Add that shift (each line moved by its standard error).
        shifts = []
        for key in PARAMS:
            moved = {k: dict(v) for k, v in lines.items()}
            moved[key]["intercept"] += lines[key]["stderr_at_mean"]
            moved_fit = fit_presliding(rec, moved, runs, sigma0=pre["sigma0"])
            assert moved_fit is not None  # same record, same stretches
            shifts.append(moved_fit["sigma1"] - pre["sigma1"])
        from_lines = math.sqrt(sum(d * d for d in shifts)) / pre["sigma1"]
        pre["sigma1_rel_err"] = math.hypot(pre["sigma1_rel_err"], from_lines)
    p_mid = 0.5 * (p_lo + p_hi)
    doc: dict[str, Any] = {k: lines[k] for k in PARAMS}
    s0_default = line_at(lines, "Fs", p_mid) / DEFAULT_PRESLIDING_DISPLACEMENT_M
    # The reversals' initial slope (any pre-sliding law): used unless the reversals start as
    # LuGre's do and the LuGre simulation above identified sigma0.
    slope = fit_initial_slope(rec, lines, runs)
    sim_ok = pre is not None and pre["sigma0_rel_err"] <= PRESLIDING_MAX_REL_ERR
    slope_ok = slope is not None and slope["sigma0_rel_err"] <= PRESLIDING_MAX_REL_ERR
    method = "lugre-simulation" if sim_ok else None
    if slope_ok and not (sim_ok and slope["lugre_shape"]):
        lugre = slope["lugre_shape"]
        method = "initial-slope (LuGre start)" if lugre else "initial-slope (elastic start)"
        s0 = slope["lugre_sigma0"] if lugre else slope["sigma0"]
        s1, src = s0 * DEFAULT_DAMPING_TIME_S, "fitted sigma0, default sigma1"
        how = ("half the initial stiffness of LuGre's exponential start" if lugre else
               "the initial stiffness of the seal's elastic (linear) start")
        warnings.append(f"sigma0 from the slow reversals' initial slope ({how}: {s0:.3g} N/m over "
                        f"{slope['turns']} reversals{'' if lugre else ', not a LuGre seal'}); "
                        f"sigma1 = {DEFAULT_DAMPING_TIME_S:g} s x sigma0")
    elif pre is None:
        warnings.append("sigma0, sigma1: no pre-sliding data (slow reversals) in the record; using defaults")
        s0, s1, src = s0_default, s0_default * DEFAULT_DAMPING_TIME_S, "default"
    elif pre["sigma0_rel_err"] > PRESLIDING_MAX_REL_ERR:
        warnings.append(f"sigma0, sigma1: pre-sliding data do not determine sigma0 (relative error "
                        f"{pre['sigma0_rel_err']:.2f}); using defaults")
        s0, s1, src = s0_default, s0_default * DEFAULT_DAMPING_TIME_S, "default"
    elif pre["sigma1_rel_err"] > SIGMA1_MAX_REL_ERR:
        s0 = pre["sigma0"]
        s1, src = s0 * DEFAULT_DAMPING_TIME_S, "fitted sigma0, default sigma1"
        warnings.append(f"sigma1: pre-sliding data do not determine it (relative error "
                        f"{pre['sigma1_rel_err']:.2f}); using sigma1 = {DEFAULT_DAMPING_TIME_S:g} s x sigma0")
    else:
        s0, s1, src = pre["sigma0"], pre["sigma1"], "fitted"
    if src == "default":
        warnings[-1] += (f" sigma0 = Fs({p_mid:.1f} MPa)/{DEFAULT_PRESLIDING_DISPLACEMENT_M:g} m = {s0:.3g} N/m, "
                         f"sigma1 = {DEFAULT_DAMPING_TIME_S:g} s x sigma0 = {s1:.3g} N s/m")
    doc["sigma0"], doc["sigma1"] = s0, s1
    # what the pre-sliding fit found, also when it was not used
    found = {(k + "_fit" if k in ("sigma0", "sigma1") else k): v for k, v in (pre or {}).items()}
    doc["presliding"] = {"source": src, "method": method, **found,
                         "initial_slope": None if slope is None else
                         {k: (bool(v) if k == "lugre_shape" else v) for k, v in slope.items()}}
    holds = standstill_holds(rec, runs)
    if holds:
        ratio = float(np.median([h["ratio"] for h in holds]))
        doc["standstill_hold_ratio"] = ratio
        doc["standstills"] = holds
        if ratio < MIN_STANDSTILL_HOLD:
            warnings.append(f"standstill: the seal held {round(ratio * 100)} % of its sliding force when the piston "
                            f"stopped (median of {len(holds)}); a LuGre seal holds nearly all of it. "
                            "This seal does not follow the node's model: `ropemon config` refuses it")
    else:
        warnings.append("standstill: no standstill after a run in the record: whether the seal holds its "
                        "force at rest is not checked (see the test procedure)")
    doc["pressure_range_MPa"] = [p_lo, p_hi]
    doc["levels"] = [{"pressure_MPa": lv.pressure_MPa, "points": len(lv.v), "rms_N": lv.rms_N,
                      **lv.params, "stderr": lv.stderr} for lv in levels]
    doc["residual"] = residual(rec, doc)
    w = residual_warning(doc["residual"])
    if w:
        warnings.append(w)
    doc["source"] = source
    doc["warnings"] = warnings
    return doc, levels, warnings


# ---------------------------------------------------------------- plots


def write_plots(directory: Path, rec: Record, doc: dict[str, Any], levels: list[Level]) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    directory.mkdir(parents=True, exist_ok=True)
    out = []
    fig, ax = plt.subplots(figsize=(8, 5))
    cmap = plt.get_cmap("viridis")
    for i, lv in enumerate(levels):
        c = cmap(i / max(len(levels) - 1, 1))
        ax.plot(lv.v * 1e3, lv.F / 1e3, "o", color=c, ms=4)
        vmax = float(np.max(np.abs(lv.v)))
        vv = np.concatenate([-np.geomspace(vmax, vmax / 1e3, 200), np.geomspace(vmax / 1e3, vmax, 200)])
        pr = lv.params
        ax.plot(vv * 1e3, steady_force(vv, pr["Fs"], pr["Fc"], pr["vs"], pr["sigma2"]) / 1e3, "-", color=c,
                label=f"{lv.pressure_MPa:.1f} MPa")
    ax.set_xscale("symlog", linthresh=1.0)
    ax.set_xlabel("piston velocity (mm/s)")
    ax.set_ylabel("friction (kN)")
    ax.set_title("Steady-state friction: runs (points) and Stribeck fits (lines)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    path = directory / "friction-velocity.png"
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    out.append(path)

    fig, axes = plt.subplots(2, 2, figsize=(9, 6))
    p = np.array([lv.pressure_MPa for lv in levels])
    pp = np.linspace(0, p.max() * 1.1, 50)
    scale = {"Fs": (1e-3, "kN"), "Fc": (1e-3, "kN"), "vs": (1e3, "mm/s"), "sigma2": (1e-3, "kN s/m")}
    for ax, key in zip(axes.flat, PARAMS):
        k, unit = scale[key]
        y = np.array([lv.params[key] for lv in levels])
        err = np.array([lv.stderr[key] for lv in levels])
        ax.errorbar(p, y * k, yerr=np.nan_to_num(err) * k, fmt="o", ms=4)
        ax.plot(pp, line_at(doc, key, pp) * k, "-")
        ax.set_title(f"{key}: r = {doc[key]['r']:.3f}")
        ax.set_xlabel("pressure (MPa)")
        ax.set_ylabel(f"{key} ({unit})")
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    path = directory / "parameters-pressure.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    out.append(path)
    return out


# ---------------------------------------------------------------- command


def add_arguments(p) -> None:
    p.add_argument("data", metavar="DATA.csv", help="test-bed record: time_s, pressure_MPa, velocity_m_s, friction_N")
    p.add_argument("--out", default="friction.json", help="friction fit to write (default: friction.json)")
    p.add_argument("--plots", metavar="DIR", help="write PNG plots of the fit into DIR")


def summary(doc: dict[str, Any]) -> str:
    rows = [f"{'param':7} {'slope':>12} {'intercept':>12} {'r':>7}  unit"]
    for key in PARAMS:
        d = doc[key]
        rows.append(f"{key:7} {d['slope']:12.5g} {d['intercept']:12.5g} {d['r']:7.3f}  {d['slope_unit']}, {d['unit']}")
    rows.append(f"sigma0  {doc['sigma0']:.4g} N/m, sigma1 {doc['sigma1']:.4g} N s/m ({doc['presliding']['source']})")
    levels = ", ".join(f"{lv['pressure_MPa']:.2f}" for lv in doc["levels"])
    rows.append(f"levels  {levels} MPa")
    return "\n".join(rows)


def check_lines(chk: BedCheck) -> list[str]:
    """The check's figures as printed (stderr), one line per part, held out and as written."""
    rows = []
    for name, figs in (("held out", chk.parts if chk.held_out else None), ("as written", chk.in_sample)):
        if figs is not None:
            rows += [f"check on the bed's force ({name}): {chk.line(part, figs)}" for part in BED_CHECK_PARTS]
    return rows


def run(args) -> int:
    try:
        rec = read_csv(args.data)
        doc, levels, warnings = fit(rec, source=Path(args.data).name)
        chk = check_bed(rec, doc)
    except FitError as e:
        print(f"fit-friction: error: {e}", file=sys.stderr)
        return 1
    except ValueError as e:  # the node's reference cannot take the fit (site.check_friction, physical)
        print(f"fit-friction: error: the node's float reference cannot run this fit on the bed: {e}", file=sys.stderr)
        return 1
    for line in check_lines(chk):
        print(f"fit-friction: {line}", file=sys.stderr)
    if chk.verdict == "worse":
        print(f"fit-friction: error: the fit reads the bed's force worse than raw p x A: {chk.worst_line()}: "
              f"{chk.worst_harm:.0f} N rms more, beyond the tolerance {chk.tol_N:.0f} N ({BED_CHECK_NOISE_SIGMAS:g} x "
              f"the bed's force noise {chk.noise_N:.0f} N); nothing written (docs/commissioning.md, "
              "\"fit-friction's check\")", file=sys.stderr)
        return 1
    if chk.verdict == "marginal":
        warnings.append(f"check: the fit reads the bed's force no better than raw p x A: {chk.worst_line()}: "
                        f"{chk.worst_harm:.0f} N rms more (within the tolerance {chk.tol_N:.0f} N): accepted, but "
                        "it does not improve the reading there")
    doc["check"] = chk.as_dict()
    doc["warnings"] = warnings
    for w in warnings:
        print(f"fit-friction: warning: {w}", file=sys.stderr)
    out = Path(args.out)
    out.write_text(json.dumps(doc, indent=2) + "\n")
    print(summary(doc))
    print(residual_table(doc["residual"]))
    print(f"wrote {out}")
    if args.plots:
        for path in write_plots(Path(args.plots), rec, doc, levels):
            print(f"wrote {path}")
    return 0


# ---------------------------------------------------------------- the fit's own check

# The bed knows the true force (its force sensor): the node's float reference
# (ropemon.commission.reference) is run over the bed's record with the fitted seal and without
# friction compensation (raw p x A), each against the bed's force. Its error there is the bed's
# friction minus the node's estimate of it (raw p x A: the whole friction). A fit whose RMS error,
# over the whole record, the sliding samples or the samples at rest (slower than a quarter of vs:
# reversals and standstills), exceeds raw p x A's by more than BED_CHECK_NOISE_SIGMAS times the
# bed's force noise is refused; by less, but worse than raw, accepted with a warning.
BED_CHECK_NOISE_SIGMAS = 3.0
BED_CHECK_PARTS = ("all", "sliding", "rest")
BED_CHECK_MIN_LEVELS = MIN_LEVELS + 1   # a level can be left out of the lines when the others still give them


def _bed_segments(rec: Record) -> list[tuple[int, int]]:
    """The record's stretches between time gaps (a pressure level each, from rest)."""
    dt = _sample_period(rec)
    cuts = [0] + (np.flatnonzero(np.diff(rec.t) > 5 * dt) + 1).tolist() + [len(rec.t)]
    return [(a, b) for a, b in zip(cuts, cuts[1:]) if b > a]


def bed_physical(rec: Record, fr: dict[str, Any], x: np.ndarray, p_max_MPa: float) -> dict[str, Any]:
    """A one-cylinder `physical` section of the node for the bed: the shipped default's
    settings (ropemon.commission.nodejson.example_physical: velocity filter, observer, play)
    at the bed's sample rate, without a compliance (the bed's displacement is the piston's),
    channels spanning the record's pressure and position, and the friction `fr`, its lines held
    above `p_max_MPa` (the top of the tested range, as `ropemon config` holds them)."""
    from ropemon.commission.nodejson import example_physical

    ph = example_physical()
    fs = int(round(1.0 / _sample_period(rec)))
    lo, hi = float(np.min(x)), float(np.max(x))
    span = max(hi - lo, 0.01)
    x_lo, x_hi = lo - 0.1 * span, hi + 0.1 * span
    p_top = max(25e6, 1.3 * float(np.max(rec.p)) * 1e6)
    one = {"ropes": 1, "sample_hz": fs, "frame_hz": next(f for f in (10, 5, 2, 1) if fs % f == 0),
           "cylinder_area_m2": ph["cylinder_area_m2"][:1],
           "pressure_channels": [{"counts_4mA": 9600, "counts_20mA": 48000, "range_Pa": [0.0, p_top]}],
           "displacement_channels": [{"counts_lo": 9600, "counts_hi": 48000, "range_m": [x_lo, x_hi]}],
           "stroke_m": [2 * max(abs(x_lo), abs(x_hi)) + 0.02],
           "piston_speed_max_m_s": max(ph["piston_speed_max_m_s"], 1.5 * float(np.max(np.abs(rec.v)))),
           "loss": dict(ph["loss"], dp_Pa=ph["loss"]["dp_Pa"][:1]),
           "friction": fr, "friction_p_max_MPa": p_max_MPa}
    ph.update(one)
    return ph


def node_friction(rec: Record, fr: dict[str, Any] | None, p_max_MPa: float,
                  span: tuple[int, int] | None = None) -> np.ndarray:
    """The friction (N) the node's float reference estimates over the record (or the samples
    `span` of it), from its position (the bed's velocity integrated from rest at each level's
    start) and pressure, with the friction section `fr` (its lines, sigma0, sigma1); None:
    no friction compensation (0)."""
    from ropemon.commission.reference import compensate

    a, b = span if span is not None else (0, len(rec.t))
    if fr is None:
        return np.zeros(b - a)
    out = np.empty(b - a)
    for s, e in _bed_segments(Record(rec.t[a:b], rec.p[a:b], rec.v[a:b], rec.F[a:b])):
        s, e = s + a, e + a
        dts = np.diff(rec.t[s:e])
        x = np.concatenate([[0.0], np.cumsum(0.5 * (rec.v[s:e - 1] + rec.v[s + 1:e]) * dts)])
        sub = Record(rec.t[s:e], rec.p[s:e], rec.v[s:e], rec.F[s:e])
        ph = bed_physical(sub, fr, x, p_max_MPa)
        pc, dc = ph["pressure_channels"][0], ph["displacement_channels"][0]
        r = np.zeros((e - s, 6), np.uint16)
        r[:, 0] = np.clip(np.round(pc["counts_4mA"] + sub.p * 1e6 / pc["range_Pa"][1]
                                   * (pc["counts_20mA"] - pc["counts_4mA"])), 0, 65535)
        (x_lo, x_hi) = dc["range_m"]
        r[:, 1] = np.clip(np.round(dc["counts_lo"] + (x - x_lo) / (x_hi - x_lo)
                                   * (dc["counts_hi"] - dc["counts_lo"])), 0, 65535)
        r[:, 2], r[:, 3] = 60000, 0xFFFF
        out[s - a:e - a] = compensate(ph, r).friction_n[:, 0]
    return out


def force_noise_N(rec: Record, runs: list[tuple[int, int]]) -> float:
    """The bed's force noise (N rms): the robust spread of the force's second differences over
    sqrt(6), within the settled halves of the runs (where the friction is steady)."""
    d = np.concatenate([np.diff(rec.F[a:b], 2) for a, b in runs if b - a > 2] or [np.zeros(1)])
    return 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(6)


def _lines_without(doc: dict[str, Any], drop: set[int]) -> dict[str, Any]:
    """The friction lines fitted to the per-level Stribeck parameters of every level but `drop`."""
    keep = [lv for i, lv in enumerate(doc["levels"]) if i not in drop]
    p = np.array([lv["pressure_MPa"] for lv in keep])
    out = {}
    for key in PARAMS:
        slope, icpt = np.polyfit(p, np.array([lv[key] for lv in keep]), 1)
        out[key] = {"slope": float(slope), "intercept": float(icpt)}
    return out


def _errors(err: np.ndarray, raw: np.ndarray) -> dict[str, Any] | None:
    if not err.size:
        return None
    return {"samples": int(err.size),
            "fit_rms_N": float(np.sqrt(np.mean(err ** 2))), "fit_max_N": float(np.max(np.abs(err))),
            "raw_rms_N": float(np.sqrt(np.mean(raw ** 2))), "raw_max_N": float(np.max(np.abs(raw)))}


@dataclass
class BedCheck:
    """The fit checked on the bed (`check_bed`): per part the node's error on the bed's force
    with the fit and raw p x A, the bed's force noise, the tolerance, on which data."""

    parts: dict[str, dict[str, Any] | None]       # held-out (or in-sample) figures per part
    in_sample: dict[str, dict[str, Any] | None]   # the fit as written on its whole record
    held_out: bool                                # parts are of levels left out of the lines
    noise_N: float
    tol_N: float

    def harm(self, part: str, figures: dict[str, dict[str, Any] | None] | None = None) -> float | None:
        """How much larger the fit's RMS error is than raw p x A's in `part` (N; < 0: smaller)."""
        c = (self.parts if figures is None else figures).get(part)
        return None if c is None else c["fit_rms_N"] - c["raw_rms_N"]

    @property
    def worst(self) -> tuple[str, str]:
        """(figures, part) where the fit does least well against raw p x A: figures 'parts'
        (held out, or in-sample) or 'in_sample' (the fit as written on its whole record)."""
        cands = [(name, part) for name in ("parts", "in_sample") for part in BED_CHECK_PARTS
                 if self.harm(part, getattr(self, name)) is not None]
        return max(cands, key=lambda c: self.harm(c[1], getattr(self, c[0])))

    @property
    def worst_harm(self) -> float:
        name, part = self.worst
        return self.harm(part, getattr(self, name))

    @property
    def verdict(self) -> str:
        """'worse' (refused), 'marginal' (worse than raw p x A within the tolerance), 'ok'."""
        h = self.worst_harm
        return "worse" if h > self.tol_N else ("marginal" if h > 0 else "ok")

    def worst_line(self) -> str:
        name, part = self.worst
        which = ("the fit as written, on its whole record" if name == "in_sample" or not self.held_out else
                 "each level against the lines of the other levels")
        return f"{self.line(part, getattr(self, name))} ({which})"

    def line(self, part: str, figures: dict[str, dict[str, Any] | None] | None = None) -> str:
        c = (figures or self.parts)[part]
        if c is None:
            return f"{part}: no samples"
        return (f"{part} ({c['samples']} samples): with the fit {c['fit_rms_N']:.0f} N rms ({c['fit_max_N']:.0f} "
                f"N worst), raw p x A {c['raw_rms_N']:.0f} N rms ({c['raw_max_N']:.0f} N worst)")

    def as_dict(self) -> dict[str, Any]:
        name, part = self.worst
        return {"verdict": self.verdict,
                "data": "held-out levels" if self.held_out else "the fit's own record",
                "noise_N": self.noise_N, "tolerance_N": self.tol_N,
                "worst": {"figures": "in_sample" if name == "in_sample" or not self.held_out else "held_out",
                          "part": part, "harm_N": self.worst_harm},
                "held_out": self.parts if self.held_out else None, "in_sample": self.in_sample}


def check_bed(rec: Record, doc: dict[str, Any], runs: list[tuple[int, int]] | None = None) -> BedCheck:
    """Run the node's float reference over the bed's record with the fit `doc` and without
    friction compensation, each against the bed's force (its error there: the node's friction
    minus the bed's; raw p x A's: minus the bed's friction), RMS and worst, over all samples,
    the sliding ones and those at rest (slower than a quarter of the fit's vs, or within the
    velocity's noise band: reversals and standstills).

    Held out: with BED_CHECK_MIN_LEVELS or more pressure levels each level (the record between
    time gaps) is run with the lines fitted to the other levels' Stribeck parameters (sigma0,
    sigma1 as fitted), so no level is checked against lines it gave; the verdict is on those
    figures and on those of the fit as written over its whole record (`in_sample`), whichever
    is worse against raw p x A (the lines as written must read the bed too). With fewer levels
    only the latter (`held_out` false).
    """
    from ropemon.commission.site import check_friction, SiteError

    runs = find_runs(rec) if runs is None else runs
    top = float(doc["pressure_range_MPa"][1])
    fr = check_friction(doc, top, refuse_unheld=False)
    vm, floor = _velocity_smooth(rec)
    p = _median_filter(rec.p, 5)
    rest = np.abs(vm) < np.maximum(line_at(doc, "vs", p) / 4, 4 * floor)
    raw = -rec.F
    masks = {"all": np.ones(len(rest), bool), "sliding": ~rest, "rest": rest}

    def parts(err: np.ndarray) -> dict[str, dict[str, Any] | None]:
        return {k: _errors(err[m], raw[m]) for k, m in masks.items()}

    full = node_friction(rec, fr, top) - rec.F
    in_sample = parts(full)
    held = None
    lv_p = np.array([lv["pressure_MPa"] for lv in doc["levels"]])
    if len(lv_p) >= BED_CHECK_MIN_LEVELS:
        held = np.empty(len(rec.t))
        for a, b in _bed_segments(rec):
            seg = p[a:b]
            near = np.abs(lv_p[:, None] - seg[None, :]) <= np.maximum(LEVEL_GAP_MPA, 0.1 * lv_p[:, None])
            drop = set(np.flatnonzero(near.mean(axis=1) > 0.05).tolist())
            if len(lv_p) - len(drop) < MIN_LEVELS:
                held = None
                break
            try:
                lines = check_friction(dict(doc, **_lines_without(doc, drop)), top, refuse_unheld=False)
            except SiteError:   # the other levels' lines are not physical at this level's pressure
                held = None
                break
            held[a:b] = node_friction(rec, lines, top, (a, b)) - rec.F[a:b]
    noise = force_noise_N(rec, runs)
    return BedCheck(parts(held) if held is not None else in_sample, in_sample, held is not None, noise,
                    BED_CHECK_NOISE_SIGMAS * noise)
