"""Dense reference integrators on the numpy model: ROS2 and BDF2 (the stepper's default, see
`stepper.integrate_fast` and docs/simulator.md for why), and the solve_ivp baseline.

Fixed-step, linearly implicit 2-stage Rosenbrock method (ROS2):

ROS2 (Verwer, Spee, Blom, Hundsdorfer, SIAM J. Sci. Comput. 1999), gamma = 1 + 1/sqrt(2):

    W = I - gamma h J(t_k, y_k)
    W k1 = f(t_k, y_k)
    W k2 = f(t_k + h, y_k + h k1) - 2 k1
    y_k+1 = y_k + h (3/2 k1 + 1/2 k2)

It is L-stable (the bulk-modulus and LuGre modes far beyond 1/h are damped, not
amplified), second order for any W (so the stage at t + h needs no time derivative
of the inputs), and costs one Jacobian, one matrix inverse and two right-hand
sides per step: no Newton iteration. The step is fixed so that every sample the
node sees lies on the grid; docs/simulator.md gives the choice and the
convergence check. The state is scaled (pressures in MPa, flows in L/s, z in um)
before the linear solve so W is well conditioned.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


def state_scale(plant) -> np.ndarray:
    """Typical magnitude of each state component (SI)."""
    s = np.ones(plant.size)
    s[plant.ip] = 1e6
    s[plant.ipj] = 1e6
    s[plant.iq] = 1e-3
    s[plant.ix] = 1e-3
    s[plant.iv] = 1e-3
    s[plant.iz] = 1e-6
    s[0] = 1e-2
    s[1] = 1e-2
    return s


def integrate(plant, u, h: float, y0: np.ndarray,
              progress: Callable[[int, int], None] | None = None, method: str = "ros2") -> np.ndarray:
    """States at every grid time u.t[k] (k = 0..K-1), shape (K, n): dense ROS2, or with method
    "bdf2" the constant-step form of the stepper's BDF2 (the reference the stepper is tested against)."""
    if method == "bdf2":
        return _integrate_bdf2(plant, u, h, y0)
    K = len(u.t)
    n = plant.size
    Y = np.empty((K, n))
    Y[0] = y0
    y = y0.copy()
    sc = state_scale(plant)
    inv_sc = 1.0 / sc
    # J in scaled variables: D^-1 J D, with D = diag(sc)
    jscale = np.outer(inv_sc, sc)
    eye = np.eye(n)
    gh = GAMMA * h
    rhs = plant.rhs
    inv = np.linalg.inv
    every = max(K // 100, 1)
    for k in range(K - 1):
        f0, J = rhs(u, k, y, True)
        Wi = inv(eye - gh * (J * jscale))
        k1 = Wi @ (f0 * inv_sc)          # scaled
        f1 = rhs(u, k + 1, y + h * (k1 * sc))
        k2 = Wi @ (f1 * inv_sc - 2.0 * k1)
        y = y + h * sc * (1.5 * k1 + 0.5 * k2)
        Y[k + 1] = y
        if progress is not None and k % every == 0:
            progress(k, K)
    if not np.all(np.isfinite(Y[-1])):
        raise FloatingPointError("the plant state became non-finite: step too large for this scenario?")
    return Y


def _integrate_bdf2(plant, u, h: float, y0: np.ndarray) -> np.ndarray:
    """Constant-step BDF2 y+ - 4/3 y + 1/3 y- = 2/3 h f(t+h, y+), one Newton step from the linear
    extrapolation 2 y - y-; the first step linearly implicit Euler. Dense scaled solves."""
    K = len(u.t)
    n = plant.size
    Y = np.empty((K, n))
    Y[0] = y0
    sc = state_scale(plant)
    jscale = np.outer(1.0 / sc, sc)
    eye = np.eye(n)
    if getattr(plant.friction, "solve_states", None) is not None:
        return _integrate_bdf2_settled(plant, u, h, y0, Y, sc, jscale, eye)
    for k in range(K - 1):
        y = Y[k]
        if k == 0:
            f, J = plant.rhs(u, 1, y, True)
            Y[1] = y + h * sc * np.linalg.solve(eye - h * (J * jscale), f / sc)
            continue
        yp = 2.0 * y - Y[k - 1]
        c = 2.0 / 3.0 * h
        f, J = plant.rhs(u, k + 1, yp, True)
        res = c * f - (yp - 4.0 / 3.0 * y + 1.0 / 3.0 * Y[k - 1])
        Y[k + 1] = yp + sc * np.linalg.solve(eye - c * (J * jscale), res / sc)
    if not np.all(np.isfinite(Y[-1])):
        raise FloatingPointError("the plant state became non-finite: step too large for this scenario?")
    return Y


def _integrate_bdf2_settled(plant, u, h, y0, Y, sc, jscale, eye):
    """`_integrate_bdf2` for a law whose states each step solves exactly (`solve_states`:
    Maxwell-slip, elasto-plastic): every step by the stepper's Newton iteration
    (`stepper._newton_settled`), here with dense solves."""
    from ropemon.lab.plant.stepper import _newton_settled, settle_rows

    law, n, nz = plant.friction, plant.n, plant.nz

    def rhs(k, y, jac):
        return plant.rhs(u, k, np.asarray(y, dtype=float), jac)

    def factor(J, c):
        return eye - c * (J * jscale)

    def solve(W, b):
        return list(sc * np.linalg.solve(W, np.asarray(b) / sc))

    def settle(y, zh, c):
        settle_rows(law.solve_states, n, nz, y, zh, c)

    zrows, vrows = plant.iz, plant.iv
    for k in range(len(u.t) - 1):
        y = Y[k].tolist()
        if k == 0:
            f, J = rhs(1, y, True)
            Y[1] = _newton_settled(rhs, factor, solve, settle, 1, h, y, f, J, y, zrows, vrows)
            continue
        yp = (2.0 * Y[k] - Y[k - 1]).tolist()
        c = 2.0 / 3.0 * h
        f, J = rhs(k + 1, yp, True)
        hist = (4.0 / 3.0 * Y[k] - 1.0 / 3.0 * Y[k - 1]).tolist()
        Y[k + 1] = _newton_settled(rhs, factor, solve, settle, k + 1, c, yp, f, J, hist, zrows, vrows)
    if not np.all(np.isfinite(Y[-1])):
        raise FloatingPointError("the plant state became non-finite: step too large for this scenario?")
    return Y


class _InputsAt:
    """The grid inputs linearly interpolated at any time, presented as a one-row Inputs (index 0)."""

    def __init__(self, u):
        self.u = u
        self.h = float(u.t[1] - u.t[0])
        self.last = self.u.take(np.array([0]))

    def at(self, t: float):
        K = len(self.u.t)
        x = min(max(t / self.h, 0.0), K - 1.0)
        k = min(int(x), K - 2)
        w = x - k
        fields = {}
        for name, v in self.u.__dict__.items():
            fields[name] = (v[k] + w * (v[k + 1] - v[k]))[None]
        return type(self.u)(**fields)


def integrate_solve_ivp(plant, u, y0: np.ndarray, t_eval: np.ndarray, method: str = "Radau",
                        rtol: float = 1e-6, atol_scale: float = 1e-6):
    """The same model with scipy's variable-step solve_ivp (the baseline); states at t_eval.

    Inputs are the grid's, linearly interpolated in time; the Jacobian is the model's analytic one;
    absolute tolerances follow the state scales (pressures in MPa, flows in L/s, ...).
    Returns (states (len(t_eval), n), number of right-hand-side evaluations).
    """
    from scipy.integrate import solve_ivp

    ui = _InputsAt(u)
    sol = solve_ivp(lambda t, y: plant.rhs(ui.at(t), 0, y), (float(t_eval[0]), float(t_eval[-1])), y0,
                    method=method, t_eval=t_eval, rtol=rtol, atol=atol_scale * state_scale(plant),
                    jac=lambda t, y: plant.rhs(ui.at(t), 0, y, True)[1])
    if not sol.success:
        raise RuntimeError(f"solve_ivp {method}: {sol.message}")
    return sol.y.T, sol.nfev
