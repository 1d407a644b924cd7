"""Accuracy metrics of a tension estimate against simulator truth.

Everything here is plain numpy on arrays the caller hands in, so the figures of
`ropemon evaluate` (docs/evaluation/, docs/accuracy.md) can be checked by hand
(tests/evaluate/test_metrics.py does).

Units of the figures:
- rope errors in % of the rated rope tension (`rated_rope_tension_N`);
- total-load errors in % of the rated total, N ropes x rated rope tension;
- `pithead_total_pct`: signed error of the summed tension at the pithead rest with
  the cage empty, in % of the true total there (the paper's table: raw -17 %,
  compensated -0.4 % of the empty cage's 185.4 kN); the loaded rest as the cage
  arrived is `pithead_arrival_total_pct` (`pithead_figures`).

Samples within `SHOCK_HOLD_S` after a shock are excluded from every figure,
as the targets of issue 6 say.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ropemon.station.alarms import AlarmSettings
from ropemon.station.alarmstate import Debounce, Timing

PHASES = ("rest-pithead", "rest-bottom", "acceleration", "constant-speed",
          "deceleration", "reversal-creep")
REST_PITHEAD, REST_BOTTOM, ACCELERATION, CONSTANT_SPEED, DECELERATION, CREEP = range(6)

SHOCK_HOLD_S = 0.5
_ON_THRESHOLD = 1e-6  # deviations within this of the alarm threshold count as on it


@dataclass(frozen=True)
class PhaseRules:
    """Thresholds that split a wind into phases from the hoist's motion."""

    rest_speed_m_s: float = 0.01     # slower than this and not accelerating: at rest
    rest_accel_m_s2: float = 0.01
    creep_speed_m_s: float = 0.5     # moving slower than this: creep (and piston reversals)
    accel_m_s2: float = 0.02         # |a| above this while moving: accelerating/decelerating


def classify_phases(depth_m: np.ndarray, speed_m_s: np.ndarray, accel_m_s2: np.ndarray,
                    shaft_depth_m: float, rules: PhaseRules = PhaseRules()) -> np.ndarray:
    """Phase index (into PHASES) of every sample, from the hoist's motion (the wheel's
    speed and acceleration: the drive's phases; the cage bounces on its ropes around them).

    A rest is at the pithead when the cage is in the upper half of the shaft.
    Creep wins over acceleration: below the creep speed the pistons reverse
    and the friction state is what matters, not the acceleration.
    """
    depth_m = np.asarray(depth_m, float)
    u = np.asarray(speed_m_s, float)
    a = np.asarray(accel_m_s2, float)
    phase = np.full(u.shape, CONSTANT_SPEED, dtype=np.int8)
    speeding_up = (np.abs(a) > rules.accel_m_s2) & (u * a > 0)
    slowing = (np.abs(a) > rules.accel_m_s2) & (u * a <= 0)
    phase[speeding_up] = ACCELERATION
    phase[slowing] = DECELERATION
    phase[np.abs(u) < rules.creep_speed_m_s] = CREEP
    rest = (np.abs(u) < rules.rest_speed_m_s) & (np.abs(a) < rules.rest_accel_m_s2)
    top = depth_m < 0.5 * shaft_depth_m
    phase[rest & top] = REST_PITHEAD
    phase[rest & ~top] = REST_BOTTOM
    return phase


def detect_shocks(t_s: np.ndarray, tension_n: np.ndarray, rated_n: float,
                  rate_frac_per_s: float = 0.5) -> np.ndarray:
    """Onset times of shocks: where any true rope tension changes faster than
    `rate_frac_per_s` x rated per second (payload dropped on or off, a jerk).

    Only the first sample of each run above the rate is an onset.
    """
    t_s = np.asarray(t_s, float)
    tension_n = np.atleast_2d(np.asarray(tension_n, float).T).T
    if len(t_s) < 2:
        return np.zeros(0)
    rate = np.abs(np.diff(tension_n, axis=0)) / np.diff(t_s)[:, None]
    fast = np.concatenate([[False], (rate > rate_frac_per_s * rated_n).any(axis=1)])
    onset = fast & ~np.concatenate([[False], fast[:-1]])
    return t_s[onset]


def shock_mask(t_s: np.ndarray, shock_times_s, hold_s: float = SHOCK_HOLD_S) -> np.ndarray:
    """True for samples in [shock, shock + hold_s) of any shock: excluded from figures."""
    t_s = np.asarray(t_s, float)
    excluded = np.zeros(t_s.shape, bool)
    for ts in np.asarray(shock_times_s, float).ravel():
        excluded |= (t_s >= ts) & (t_s < ts + hold_s)
    return excluded


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")


def _peak(x: np.ndarray) -> float:
    return float(np.max(np.abs(x))) if x.size else float("nan")


def error_figures(est_n: np.ndarray, truth_n: np.ndarray, rated_n: float,
                  keep: np.ndarray) -> dict:
    """RMS and peak errors over the samples where `keep` is True.

    est_n, truth_n: (samples, ropes) in N. Rope figures in % of rated rope
    tension (`rope_*` are the worst rope), total in % of ropes x rated. A NaN
    estimate (the node flagged the rope's sensors and gave no tension) is not
    an error: it is left out and counted in `no_tension_samples`.
    """
    est_n = np.asarray(est_n, float)
    truth_n = np.asarray(truth_n, float)
    err = (est_n - truth_n)[keep] / rated_n * 100.0
    has = np.isfinite(err)
    total = (est_n.sum(axis=1) - truth_n.sum(axis=1))[keep] / (rated_n * est_n.shape[1]) * 100.0
    per_rms = [_rms(err[has[:, i], i]) for i in range(err.shape[1])]
    per_peak = [_peak(err[has[:, i], i]) for i in range(err.shape[1])]
    return {
        "samples": int(keep.sum()),
        "no_tension_samples": int((~has).any(axis=1).sum()),
        "rope_rms_pct": _worst(per_rms),
        "rope_peak_pct": _worst(per_peak),
        "per_rope_rms_pct": per_rms,
        "per_rope_peak_pct": per_peak,
        "total_rms_pct": _rms(total[np.isfinite(total)]),
        "total_peak_pct": _peak(total[np.isfinite(total)]),
    }


def _worst(values: list[float]) -> float:
    finite = [v for v in values if np.isfinite(v)]
    return max(finite) if finite else float("nan")


def pithead_rest(phase: np.ndarray, excluded: np.ndarray, steady: np.ndarray | None = None) -> np.ndarray:
    """Samples of the pithead rest after the cage arrived there: the pithead rest samples
    after the first motion (if the cage never moved, all of them), outside shock windows,
    only where `steady` is True (the payload is not being changed)."""
    rest = (np.asarray(phase) == REST_PITHEAD) & ~np.asarray(excluded, bool)
    if steady is not None:
        rest &= np.asarray(steady, bool)
    moved = np.flatnonzero(np.asarray(phase) != REST_PITHEAD)
    if moved.size and rest[moved[0]:].any():
        rest[:moved[0]] = False
    return rest


def total_error_pct(est_n: np.ndarray, truth_n: np.ndarray, where: np.ndarray) -> float:
    """Signed error of the mean summed tension over the samples `where` (and the estimate
    has every rope), in % of the true sum there; NaN when there are none."""
    est_n = np.asarray(est_n, float)
    where = np.asarray(where, bool) & np.isfinite(est_n).all(axis=1)
    if not where.any():
        return float("nan")
    est_sum = est_n[where].sum(axis=1).mean()
    true_sum = np.asarray(truth_n, float)[where].sum(axis=1).mean()
    return float((est_sum - true_sum) / true_sum * 100.0)


def pithead_total_pct(est_n: np.ndarray, truth_n: np.ndarray, phase: np.ndarray,
                      excluded: np.ndarray, steady: np.ndarray | None = None) -> float:
    """Signed error of the summed tension over the whole pithead rest after arrival
    (`pithead_rest`), in % of the true sum."""
    return total_error_pct(est_n, truth_n, pithead_rest(phase, excluded, steady))


PITHEAD_EMPTY, PITHEAD_ARRIVAL = "empty", "arrival"  # values of `pithead_total_basis`


def pithead_figures(est_n: np.ndarray, truth_n: np.ndarray, phase: np.ndarray, excluded: np.ndarray,
                    steady: np.ndarray | None = None, payload_kg: np.ndarray | None = None) -> dict:
    """The total-load errors at the pithead rest after arrival, like the paper's table.

    - `pithead_arrival_total_pct`: the rest as the cage arrived, until its payload is
      first changed (the field trip's loaded "pithead rest");
    - `pithead_empty_total_pct`: the rest with the cage empty (payload 0 kg; the field
      trip's "pithead rest empty" after unloading). This is the paper's measurement:
      185.4 kN is the empty cage plus tail ropes;
    - `pithead_total_pct`: the empty-cage figure, or the arrival one when the scenario
      has no empty-cage pithead rest; `pithead_total_basis` says which.
    Without `payload_kg` the arrival rest is the whole pithead rest and there is no empty one.
    """
    rest = pithead_rest(phase, excluded, steady)
    arrival = rest.copy()
    empty = np.zeros_like(rest)
    if payload_kg is not None and rest.any():
        payload_kg = np.asarray(payload_kg, float)
        first = int(np.flatnonzero(rest)[0])
        changed = np.flatnonzero(payload_kg[first:] != payload_kg[first])
        if changed.size:
            arrival[first + changed[0]:] = False
        empty = rest & (payload_kg == 0.0)
    out: dict = {"pithead_arrival_total_pct": total_error_pct(est_n, truth_n, arrival),
                 "pithead_empty_total_pct": total_error_pct(est_n, truth_n, empty)}
    basis = PITHEAD_EMPTY if np.isfinite(out["pithead_empty_total_pct"]) else PITHEAD_ARRIVAL
    out["pithead_total_pct"] = out[f"pithead_{basis}_total_pct"]
    out["pithead_total_basis"] = basis
    return out


def evaluate_estimate(est_n: np.ndarray, truth_n: np.ndarray, rated_n: float,
                      phase: np.ndarray, excluded: np.ndarray, steady: np.ndarray | None = None,
                      payload_kg: np.ndarray | None = None) -> dict:
    """All accuracy figures of one estimate: whole wind, by phase, pithead totals."""
    keep = ~np.asarray(excluded, bool)
    out = error_figures(est_n, truth_n, rated_n, keep)
    out.update(pithead_figures(est_n, truth_n, phase, excluded, steady, payload_kg))
    out["by_phase"] = {name: error_figures(est_n, truth_n, rated_n, keep & (phase == k))
                       for k, name in enumerate(PHASES)}
    return out


def window_means(x: np.ndarray, window: int) -> np.ndarray:
    """Means over consecutive blocks of `window` samples (a trailing partial block is dropped)."""
    x = np.asarray(x, float)
    n = (len(x) // window) * window
    return x[:n].reshape(len(x) // window, window, *x.shape[1:]).mean(axis=1)


def deviation_from_mean(tension_n: np.ndarray) -> np.ndarray:
    """Each rope's deviation from the mean rope tension, as a fraction of the mean."""
    tension_n = np.asarray(tension_n, float)
    mean = tension_n.mean(axis=1, keepdims=True)
    return (tension_n - mean) / mean


def deviation_step_n(truth_n: np.ndarray, rope: int, deviation: float) -> np.ndarray:
    """Extra tension on `rope` that makes its true deviation from the mean exactly `deviation`.

    With T_k + dT - m - dT/N = deviation * (m + dT/N) for mean m of N ropes.
    """
    truth_n = np.asarray(truth_n, float)
    n = truth_n.shape[1]
    m = truth_n.mean(axis=1)
    return ((1.0 + deviation) * m - truth_n[:, rope]) / (1.0 - (1.0 + deviation) / n)


def debounced(times_s, raise_cond, clear_cond, timing: Timing, skip=None) -> tuple[np.ndarray, list[int]]:
    """`Debounce` over a series of evaluations (arrays): the debounced condition after each,
    and the indices where it raised. `skip[i]` (optional) drops evaluation i as if no frame
    came: a pending change restarts. Idle stretches (nothing pending) are jumped over, so
    the cost follows the evaluations where a condition holds."""
    n = len(times_s)
    rc = np.asarray(raise_cond, bool)
    cc = np.asarray(clear_cond, bool)
    if skip is not None:
        rc = rc & ~np.asarray(skip, bool)
        cc = cc & ~np.asarray(skip, bool)
    present = np.zeros(n, bool)
    raises: list[int] = []
    raise_at, clear_at = np.flatnonzero(rc), np.flatnonzero(cc)
    d = Debounce(timing)
    i = 0
    while i < n:
        if d.since_s is None:  # idle: on to the next evaluation that can start a change
            pending = clear_at if d.present else raise_at
            j = int(np.searchsorted(pending, i))
            nxt = int(pending[j]) if j < len(pending) else n
            present[i:nxt] = d.present
            i = nxt
            if i >= n:
                break
        if skip is not None and skip[i]:
            d.since_s, d.since_n = None, 0
        elif d.step(float(times_s[i]), bool(rc[i]), bool(cc[i])) == "raise":
            raises.append(i)
        present[i] = d.present
        i += 1
    return present, raises


def alarm_assessment(est_n: np.ndarray, truth_n: np.ndarray, excluded: np.ndarray,
                     window: int, threshold: float = 0.10,
                     levels=(0.08, 0.10, 0.12), frame_s: float | None = None,
                     settings: AlarmSettings = AlarmSettings()) -> dict:
    """False and missed deviation alarms when one rope really deviates by each level.

    The deviation is superposed: rope k's true tension is raised (or lowered, for
    the negative level) so that its true deviation from the mean is exactly the
    level, and the same force is added to the estimate of rope k, since the
    cylinder carries it as pressure. What remains is the estimator's own error,
    which is what can make or miss an alarm. The alarm signal is the deviation of
    frame-window means (`window` samples), as the host sees it; windows touching
    an excluded (shock) sample are skipped. Every rope and both signs are tried.

    Per level, frame by frame: `frames` assessed, `false` = frames where a rope is
    flagged whose true |deviation| is not above the threshold (levels below the
    threshold, and other ropes at any level), `missed` = frames where the deviating
    rope's true deviation is above the threshold and it is not flagged,
    `detected_frac` = share of frames the deviating rope is flagged.

    With `frame_s` (the frame period), also what the operator would see: the
    host's own debounce (`debounced`, with `settings`' deviation
    timing and hysteresis) over each rope's deviation, a skipped window counting
    as no frame. `false_alarms` = raises on a rope whose true |deviation| is not
    above the threshold; `missed_alarm_frames` = frames where the same debounce
    on the true deviation holds the deviating rope's alarm and the estimate's
    does not (so the debounce's own delay is not counted as missed).
    """
    est_n = np.asarray(est_n, float)
    truth_n = np.asarray(truth_n, float)
    ropes = truth_n.shape[1]
    keep = window_means(np.asarray(excluded, float), window) == 0.0
    hyst = settings.deviation_hysteresis_frac
    out = {}
    for level in levels:
        frames = false = missed = detected = false_alarms = missed_alarm = 0
        for rope in range(ropes):
            for sign in (1.0, -1.0):
                step = deviation_step_n(truth_n, rope, sign * level)
                t = truth_n.copy()
                e = est_n.copy()
                t[:, rope] += step
                e[:, rope] += step
                d_est_all = deviation_from_mean(window_means(e, window))
                d_true_all = deviation_from_mean(window_means(t, window))
                # a window with a rope without tension cannot be assessed
                ok = keep & np.isfinite(d_est_all).all(axis=1)
                d_true = d_true_all[ok]
                d_est = d_est_all[ok]
                flag = np.abs(d_est) > threshold
                # a true deviation on the threshold itself (the 10 % level) is
                # neither a must-alarm nor a must-not-alarm
                truly_above = np.abs(d_true) > threshold + _ON_THRESHOLD
                truly_below = np.abs(d_true) < threshold - _ON_THRESHOLD
                frames += len(d_true)
                false += int((flag & truly_below).any(axis=1).sum())
                missed += int((truly_above[:, rope] & ~flag[:, rope]).sum())
                detected += int(flag[:, rope].sum())
                if frame_s is None:
                    continue
                times = np.arange(len(ok)) * frame_s
                a_est, a_true = np.abs(d_est_all), np.abs(d_true_all)
                held_est = np.zeros(len(ok), bool)
                for r in range(ropes):
                    if not (a_est[ok, r] > threshold).any():
                        continue  # never raised: no alarm on this rope
                    present, raises = debounced(times, a_est[:, r] > threshold,
                                                a_est[:, r] < threshold - hyst, settings.timing, ~ok)
                    below = a_true[:, r] < threshold - _ON_THRESHOLD
                    false_alarms += sum(1 for i in raises if below[i])
                    if r == rope:
                        held_est = present
                held_true, _ = debounced(times, a_true[:, rope] > threshold + _ON_THRESHOLD,
                                         a_true[:, rope] < threshold - hyst, settings.timing, ~ok)
                missed_alarm += int((held_true & ~held_est & ok).sum())
        key = f"{round(level * 100):d}"
        out[key] = {"frames": frames, "false": false, "missed": missed,
                    "detected_frac": detected / frames if frames else float("nan")}
        if frame_s is not None:
            out[key].update(false_alarms=false_alarms, missed_alarm_frames=missed_alarm)
    return out


# ---------------------------------------------------------------- the station's alarm events
#
# Scored from the alarm events the station's engine gives on a wind's frames (`AlarmEvent`s or
# their `to_dict()`), times in s of node time; ropes from 0. Hand-checked in
# tests/evaluate/test_alarm_scoring.py.

DEVIATION_LIMIT = 0.10
SILENT_MIN_S = 2.0          # a rope truly beyond the limit this long must be alarmed on
STANDING_SHARE = 0.9        # an alarm present this share of the wind's motion stands through it
CHATTER_RAISES, CHATTER_S = 2, 60.0   # raised more than this many times within this: chattering
ADVISORY_KINDS = frozenset({"rope_adjust"})   # advisories: they never cover a silent rope
# alarms that are true on a healthy hoist when a rope is truly beyond the limit
TRUE_DEVIATION_KINDS = frozenset({"deviation", "node_imbalance"})


@dataclass(frozen=True)
class AlarmSpan:
    """One raise of one alarm to its clear (t_clear None: still present at the end)."""

    alarm: str
    kind: str
    node: int | None
    rope: int | None
    t_raise: float
    t_clear: float | None

    def end(self, t_end: float) -> float:
        return t_end if self.t_clear is None else self.t_clear


def _ev(e, key: str):
    return e[key] if isinstance(e, dict) else getattr(e, key)


def alarm_spans(events) -> list[AlarmSpan]:
    """The raise-to-clear spans of every alarm, in raise order. A raise not annunciated (the rope's
    sensor failed, shelved) is no span; a clear without a raise is ignored."""
    open_: dict[str, tuple] = {}
    spans: list[AlarmSpan] = []
    for e in sorted(events, key=lambda e: _ev(e, "time_s")):
        action, aid = _ev(e, "action"), _ev(e, "alarm")
        if action == "raise" and aid not in open_:
            if not (e.get("annunciated", True) if isinstance(e, dict) else getattr(e, "annunciated", True)):
                continue
            open_[aid] = (_ev(e, "kind"), _ev(e, "node"), _ev(e, "rope"), float(_ev(e, "time_s")), len(spans))
            spans.append(None)  # type: ignore[arg-type]
        elif action == "clear" and aid in open_:
            kind, node, rope, t0, k = open_.pop(aid)
            spans[k] = AlarmSpan(aid, kind, node, rope, t0, float(_ev(e, "time_s")))
    for aid, (kind, node, rope, t0, k) in open_.items():
        spans[k] = AlarmSpan(aid, kind, node, rope, t0, None)
    return spans


def _beyond_during(beyond_t: np.ndarray | None, beyond: np.ndarray | None, rope: int | None,
                   t0: float, t1: float) -> bool:
    """Whether a rope (any rope: None) was truly beyond the limit at any time in [t0, t1]."""
    if beyond is None or beyond_t is None:
        return False
    m = (beyond_t >= t0) & (beyond_t <= t1)
    b = beyond[m] if rope is None else beyond[m, rope]
    return bool(np.any(b))


def excluded_span(s: AlarmSpan, t_end: float, beyond_t=None, beyond=None) -> str | None:
    """Why a healthy hoist's alarm does not count against it (None: it counts): NODE SILENT after
    the wind's last frame, or a deviation alarm (DEVIATION on a rope, the node's own imbalance
    bit) while that rope (any rope) was truly beyond the limit, from SILENT_MIN_S before its raise."""
    if s.kind == "silent" and s.t_raise >= t_end:
        return "node silent after the wind"
    if s.kind in TRUE_DEVIATION_KINDS and _beyond_during(beyond_t, beyond, s.rope, s.t_raise - SILENT_MIN_S,
                                                          s.end(t_end)):
        return "rope truly beyond the limit"
    return None


def healthy_alarm_figures(events, wind: tuple[float, float], t_end: float, beyond_t=None, beyond=None) -> dict:
    """A healthy hoist's alarms over one wind: `raised` (the raises that count), `standing` (alarms
    present for STANDING_SHARE or more of the wind's motion, `wind` = (start, end)), `chattering`
    (alarms raised more than CHATTER_RAISES times within CHATTER_S), `excluded` (raises that do not
    count, by reason: `excluded_span`), `kinds` (counting raises by kind).

    beyond_t, beyond: frame times and (frames, ropes) booleans: the rope's true deviation beyond
    the limit."""
    spans = alarm_spans(events)
    counted, excluded, kinds = [], {}, {}
    for s in spans:
        why = excluded_span(s, t_end, beyond_t, beyond)
        if why:
            excluded[why] = excluded.get(why, 0) + 1
        else:
            counted.append(s)
            kinds[s.kind] = kinds.get(s.kind, 0) + 1
    w0, w1 = wind
    standing = []
    if w1 > w0:
        for aid in sorted({s.alarm for s in counted}):
            cover = sum(max(0.0, min(s.end(t_end), w1) - max(s.t_raise, w0)) for s in counted if s.alarm == aid)
            if cover >= STANDING_SHARE * (w1 - w0):
                standing.append(aid)
    chattering = []
    for aid in sorted({s.alarm for s in counted}):
        t = sorted(s.t_raise for s in counted if s.alarm == aid)
        if any(t[i + CHATTER_RAISES] - t[i] <= CHATTER_S for i in range(len(t) - CHATTER_RAISES)):
            chattering.append(aid)
    return {"raised": len(counted), "standing": standing, "chattering": chattering, "excluded": excluded,
            "kinds": kinds}


def fault_alarm_figures(events, kinds, rope: int | None, onset_s: float, event_s: float,
                        deadline_s: float) -> dict:
    """How the station met one fault: the first raise of one of `kinds` on `rope` (None: a node's
    alarm, any rope) at or after `onset_s` (the fault's start); `latency_s` from `event_s` (the
    physical event: e.g. the piston entering its margin); `in_time` when by `deadline_s`.
    `wrong_rope`: such a raise came only on other ropes (their numbers, from 0). `raised`: every
    kind raised from the onset (counts), what the legacy station shows on the fault."""
    spans = [s for s in alarm_spans(events) if s.t_raise >= onset_s - 1e-9]
    raised: dict[str, int] = {}
    for s in spans:
        raised[s.kind] = raised.get(s.kind, 0) + 1
    mine = [s for s in spans if s.kind in kinds and (rope is None or s.rope == rope)]
    others = sorted({s.rope for s in spans if s.kind in kinds and rope is not None and s.rope != rope
                     and s.rope is not None})
    out = {"alarmed": bool(mine), "raised": raised, "wrong_rope": others if not mine else [],
           "t_alarm_s": None, "latency_s": None, "in_time": False}
    if mine:
        t = mine[0].t_raise
        out.update(t_alarm_s=round(t, 3), latency_s=round(t - event_s, 3), in_time=bool(t <= deadline_s + 1e-9))
    on_rope = [s for s in spans if rope is not None and s.rope == rope and s.kind not in ADVISORY_KINDS]
    out["any_on_rope"] = {"kind": on_rope[0].kind, "t_s": round(on_rope[0].t_raise, 3)} if on_rope else None
    return out


def silent_ropes(events, times_s: np.ndarray, d_true: np.ndarray, hidden_frac: np.ndarray | None,
                 valid: np.ndarray | None = None) -> dict:
    """Ropes the station left silent: a rope truly beyond DEVIATION_LIMIT for SILENT_MIN_S or more
    without any alarm on that rope (other than an advisory) present at any time of the episode.

    times_s: frame times; d_true: (frames, ropes) true deviations from the mean (fractions);
    hidden_frac: (frames,) or (frames, ropes) the imbalance the seals can hide as the commissioning
    states it (`uncertainty.hidden_reach` at the rope tension), or None. An episode whose true
    deviation stayed within it is `within_hidden`, else `beyond_hidden` (without hidden_frac:
    `unsplit`). valid: frames that count (not in a shock's hold)."""
    times_s = np.asarray(times_s, float)
    d = np.abs(np.asarray(d_true, float))
    ok = np.ones(len(times_s), bool) if valid is None else np.asarray(valid, bool)
    t_end = float(times_s[-1]) if len(times_s) else 0.0
    spans = [s for s in alarm_spans(events) if s.rope is not None and s.kind not in ADVISORY_KINDS]
    hid = None if hidden_frac is None else np.asarray(hidden_frac, float)
    if hid is not None and hid.ndim == 1:
        hid = np.repeat(hid[:, None], d.shape[1], axis=1)
    out: dict = {"episodes": 0, "within_hidden": [], "beyond_hidden": [], "unsplit": []}
    frame_s = float(np.median(np.diff(times_s))) if len(times_s) > 1 else 0.1
    need = int(math.ceil(SILENT_MIN_S / frame_s - 1e-9))
    for r in range(d.shape[1]):
        m = np.concatenate([[False], (d[:, r] > DEVIATION_LIMIT) & ok, [False]])
        edges = np.flatnonzero(np.diff(m.astype(int)))
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a < need:
                continue
            out["episodes"] += 1
            t0, t1 = float(times_s[a]), float(times_s[b - 1])
            if any(s.rope == r and s.t_raise <= t1 and s.end(t_end) >= t0 for s in spans):
                continue
            ep = {"rope": r + 1, "t0_s": round(t0, 1), "t1_s": round(t1, 1),
                  "true_max_pct": round(float(d[a:b, r].max()) * 100, 2)}
            if hid is None:
                out["unsplit"].append(ep)
                continue
            ep["hidden_pct"] = round(float(np.min(hid[a:b, r])) * 100, 2)
            within = bool(np.all(d[a:b, r] <= hid[a:b, r]))
            out["within_hidden" if within else "beyond_hidden"].append(ep)
    return out
