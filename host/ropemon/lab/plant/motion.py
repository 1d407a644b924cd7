"""Hoist trip motion: jerk-limited S-curve moves of the friction wheel, and rests.

A timeline is a list of constant-jerk pieces; position, speed and acceleration are
its exact piecewise-polynomial integrals, evaluated on any time grid. Depth is
positive downwards (docs/model.md), so a wind up is a move to a smaller depth.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


def scurve_pieces(distance_m: float, v_max: float, a_max: float, jerk: float) -> list[tuple[float, float]]:
    """(duration_s, jerk) pieces of a rest-to-rest move of `distance_m` (signed)."""
    d = abs(distance_m)
    if d == 0.0:
        return []
    sign = 1.0 if distance_m > 0 else -1.0

    def accel_time(v: float) -> tuple[float, float, float]:
        a = min(a_max, math.sqrt(v * jerk))
        tj = a / jerk
        ta = max(v / a - tj, 0.0)
        return a, tj, ta

    def dist_ramps(v: float) -> float:
        a, tj, ta = accel_time(v)
        return v * (2 * tj + ta)  # accelerate then decelerate: v * T_ramp

    v = v_max
    if dist_ramps(v) > d:  # the move is too short to reach v_max
        lo, hi = 0.0, v_max
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if dist_ramps(mid) <= d else (lo, mid)
        v = lo
    a, tj, ta = accel_time(v)
    tc = (d - dist_ramps(v)) / v
    j = sign * jerk
    return [(tj, j), (ta, 0.0), (tj, -j), (tc, 0.0), (tj, -j), (ta, 0.0), (tj, j)]


@dataclass
class Timeline:
    """Wheel motion from a start depth: a sequence of constant-jerk pieces."""

    start_depth_m: float
    pieces: list[tuple[float, float]] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return sum(d for d, _ in self.pieces)

    def rest(self, seconds: float) -> None:
        if seconds > 0:
            self.pieces.append((seconds, 0.0))

    def move(self, distance_m: float, v_max: float, a_max: float, jerk: float) -> None:
        self.pieces.extend(p for p in scurve_pieces(distance_m, v_max, a_max, jerk) if p[0] > 0)

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(depth m, speed m/s, acceleration m/s^2) at times t (beyond the end: at rest)."""
        t = np.asarray(t, dtype=float)
        s = np.full(t.shape, self.start_depth_m)
        u = np.zeros(t.shape)
        acc = np.zeros(t.shape)
        t0, s0, u0, a0 = 0.0, self.start_depth_m, 0.0, 0.0
        for dur, j in self.pieces:
            m = t >= t0
            tau = np.minimum(t[m] - t0, dur)
            s[m] = s0 + u0 * tau + a0 * tau ** 2 / 2 + j * tau ** 3 / 6
            u[m] = u0 + a0 * tau + j * tau ** 2 / 2
            acc[m] = a0 + j * tau
            s0, u0, a0 = s0 + u0 * dur + a0 * dur ** 2 / 2 + j * dur ** 3 / 6, u0 + a0 * dur + j * dur ** 2 / 2, a0 + j * dur
            t0 += dur
        # the ramps end at exactly zero speed and acceleration; clear rounding at rest
        rest = t >= t0
        u[rest] = 0.0
        acc[rest] = 0.0
        return s, u, acc


def piecewise_linear(points: list[tuple[float, float]], t: np.ndarray) -> np.ndarray:
    """Value of a piecewise-linear schedule [(t_s, value), ...] at times t (held beyond the ends)."""
    ts = np.array([p[0] for p in points], dtype=float)
    vs = np.array([p[1] for p in points], dtype=float)
    return np.interp(t, ts, vs)
