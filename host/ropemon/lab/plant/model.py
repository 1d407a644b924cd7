"""The plant's equations: cage on head ropes, pistons with seal friction, cavities, pipes, junction.

State y (n = 3 + 4N + N M), signs and units of docs/model.md:

    r, rd        cage depth relative to the wheel's paid-out rope (rope stretch), and its rate
    x[N], v[N]   piston positions and velocities (x > 0: pulled out by the rope)
    z[N M]       friction-law internal states, M = `friction.n_z` per rope, rope by rope
                 (M = 1: LuGre bristle deflection; M elements: Maxwell-slip)
    p[N]         cavity pressures (Pa)
    q[N]         pipe flows cavity -> connecting assembly (m^3/s)
    pj           pressure in the connecting assembly (Pa)

Equations (i over ropes):

    T_i   = max(0, F_load,i + k_i (r + y_i - x_i - delta_i) + c_i (rd + y'_i - v_i))
    m_i v_i' = T_i - p_i A_i - F_i(v_i, z_i, p_i)
    p_i'  = beta / (V0_i - A_i x_i) * (A_i v_i - q_i)
    I_i q_i' = p_i - pj - dp_i(q_i)
    pj'   = beta / Vj * (sum q_i + Q_pump)
    M r'' = M_weight g - sum T_i - M a_wheel          (hoist rig only; a bench rig holds r = 0)

The piston mass m_i (piston and rod) carries inertia only; its weight is part of the
cage, so at rest T_i = p_i A_i + F_i exactly (docs/model.md). The inputs (rope
stiffness as the hanging length changes, loads, payload, pump flow, oil
temperature) are precomputed on the solver's time grid (`Inputs`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ropemon.lab.plant.hydraulics import PathSet
from ropemon.commission.site import G_M_S2

G = G_M_S2  # one value of g for the whole package (ropemon.commission.site)


@dataclass
class Inputs:
    """Time-dependent inputs on the solver grid t[k] = k h; per-rope arrays have shape (K, N)."""

    t: np.ndarray
    k_rope: np.ndarray
    c_rope: np.ndarray
    f_load: np.ndarray
    y_load: np.ndarray
    ydot_load: np.ndarray
    a_wheel: np.ndarray
    s_wheel: np.ndarray
    u_wheel: np.ndarray
    m_weight: np.ndarray
    m_inertia: np.ndarray
    q_pump: np.ndarray
    rho: np.ndarray
    mu: np.ndarray
    oil_temp_C: np.ndarray
    payload_kg: np.ndarray

    def take(self, idx: np.ndarray) -> "Inputs":
        """The inputs at grid indices idx (e.g. the solver's step points)."""
        return Inputs(**{k: v[idx] for k, v in self.__dict__.items()})


class Plant:
    def __init__(self, *, area_m2, v0_m3, piston_mass_kg, beta_Pa, junction_volume_m3,
                 to_junction: PathSet, to_tap: PathSet, friction, offsets_m, hoist: bool):
        self.n = n = len(area_m2)
        self.A = np.asarray(area_m2, dtype=float)
        self.V0 = np.asarray(v0_m3, dtype=float)
        self.m = np.asarray(piston_mass_kg, dtype=float)
        self.beta = float(beta_Pa)
        self.Vj = float(junction_volume_m3)
        self.to_junction = to_junction
        self.to_tap = to_tap
        self.friction = friction
        self.delta = np.asarray(offsets_m, dtype=float)
        self.hoist = bool(hoist)
        self.nz = nz = int(getattr(friction, "n_z", 1))
        self.size = 3 + 4 * n + n * nz
        self.ix = slice(2, 2 + n)
        self.iv = slice(2 + n, 2 + 2 * n)
        self.iz = slice(2 + 2 * n, 2 + 2 * n + n * nz)
        o = 2 + 2 * n + n * nz
        self.ip = slice(o, o + n)
        self.iq = slice(o + n, o + 2 * n)
        self.ipj = o + 2 * n
        # structural nonzeros of the Jacobian, in the order rhs() fills them
        X, V, Z, P, Q = (np.arange(s.start, s.stop) for s in (self.ix, self.iv, self.iz, self.ip, self.iq))
        R, RD, PJ = np.zeros(n, int), np.ones(n, int), np.full(n, self.ipj)
        zr = np.repeat(np.arange(n), nz)   # rope of each z
        VZ, PZ = V[zr], P[zr]
        pairs = [(X, V), (V, R), (V, RD), (V, X), (V, V), (VZ, Z), (V, P), (Z, VZ), (Z, Z), (Z, PZ),
                 (P, X), (P, V), (P, Q), (Q, P), (Q, PJ), (Q, Q), (PJ, Q), (RD, X), (RD, V)]
        rows = [a for a, _ in pairs] + [np.array([0, 1, 1])]
        cols = [b for _, b in pairs] + [np.array([1, 0, 1])]
        self.jrows = np.concatenate(rows)
        self.jcols = np.concatenate(cols)

    # ------------------------------------------------------------------ pieces

    def tension(self, u: Inputs, k, r, rd, x, v):
        """Rope-end tension T and its slackness mask (1 where the rope pulls)."""
        e = u.f_load[k] + u.k_rope[k] * (r + u.y_load[k] - x - self.delta) + u.c_rope[k] * (rd + u.ydot_load[k] - v)
        h = e > 0.0
        return np.where(h, e, 0.0), h

    def rhs(self, u: Inputs, k: int, y: np.ndarray, jac: bool = False):
        n = self.n
        r, rd = y[0], y[1]
        x, v, z, p, q = y[self.ix], y[self.iv], y[self.iz], y[self.ip], y[self.iq]
        if self.nz > 1:
            z = z.reshape(n, self.nz)
        pj = y[self.ipj]
        kr, cr = u.k_rope[k], u.c_rope[k]
        e = u.f_load[k] + kr * (r + u.y_load[k] - x - self.delta) + cr * (rd + u.ydot_load[k] - v)
        h = e > 0.0
        T = np.where(h, e, 0.0)
        fr = self.friction.evaluate(v, z, p)
        A, m, beta = self.A, self.m, self.beta
        vol = self.V0 - A * x
        rho, mu = u.rho[k], u.mu[k]
        dp, ddp = self.to_junction.dp(q, rho, mu)
        inert = self.to_junction.inertance_per_rho * rho
        f = np.empty(self.size)
        net = A * v - q
        f[self.ix] = v
        f[self.iv] = (T - p * A - fr.F) / m
        f[self.iz] = fr.zdot.ravel()
        f[self.ip] = beta / vol * net
        f[self.iq] = (p - pj - dp) / inert
        f[self.ipj] = beta / self.Vj * (q.sum() + u.q_pump[k])
        if self.hoist:
            M = u.m_inertia[k]
            f[0] = rd
            f[1] = (u.m_weight[k] * G - T.sum()) / M - u.a_wheel[k]
        else:
            f[0] = f[1] = 0.0
        if not jac:
            return f
        hk = np.where(h, kr, 0.0)
        hc = np.where(h, cr, 0.0)
        ones = np.ones(n)
        bv = beta / vol
        if self.hoist:
            M = u.m_inertia[k]
            cage = [hk / M, hc / M, np.array([1.0, -hk.sum() / M, -hc.sum() / M])]
        else:
            cage = [0.0 * ones, 0.0 * ones, np.zeros(3)]
        F_z_m = -fr.F_z / m if self.nz == 1 else (-fr.F_z / m[:, None]).ravel()
        vals = np.concatenate([
            ones, hk / m, hc / m, -hk / m, (-hc - fr.F_v) / m, F_z_m, (-A - fr.F_p) / m,
            fr.zd_v.ravel(), fr.zd_z.ravel(), fr.zd_p.ravel(),
            bv * net * A / vol, bv * A, -bv,
            1.0 / inert, -1.0 / inert, -ddp / inert,
            (beta / self.Vj) * ones] + cage)
        J = np.zeros((self.size, self.size))
        J[self.jrows, self.jcols] = vals
        return f, J

    # ------------------------------------------------------------------ initial state

    def rest_state(self, u: Inputs) -> np.ndarray:
        """Static equilibrium at t = 0: no motion, no flow, friction unloaded (every z = 0), equal pressures.

        Hoist: sum T = M g, T_i = k_i (r - x_i - delta_i), sum A_i x_i = 0.
        Bench: T_i = F_load,i + k_i (y_i - x_i), sum A_i x_i = 0 (k = 0: x = 0, p = F/A).
        """
        A = self.A
        kr = u.k_rope[0]
        y = np.zeros(self.size)
        if self.hoist:
            p0 = u.m_weight[0] * G / A.sum()
            r = (A * (self.delta + p0 * A / kr)).sum() / A.sum()
            x = r - self.delta - p0 * A / kr
            y[0] = r
        else:
            s = u.f_load[0] + kr * u.y_load[0]
            if np.all(kr == 0):
                if self.n > 1 and not np.allclose(s / A, s[0] / A[0]):
                    raise ValueError("bench rig without load springs needs equal initial pressures")
                p0, x = s[0] / A[0], np.zeros(self.n)
            else:
                p0 = (A * s / np.where(kr > 0, kr, np.inf)).sum() / (A * A / np.where(kr > 0, kr, np.inf)).sum()
                x = np.where(kr > 0, (s - p0 * A) / np.where(kr > 0, kr, 1.0), 0.0)
        y[self.ix] = x
        y[self.ip] = p0
        y[self.ipj] = p0
        return y

    # ------------------------------------------------------------------ truth outputs

    def outputs(self, u: Inputs, Y: np.ndarray) -> dict[str, np.ndarray]:
        """Every truth quantity at every grid time, vectorised over time (Y has shape (K, n))."""
        r, rd = Y[:, 0:1], Y[:, 1:2]
        x, v, z, p, q = Y[:, self.ix], Y[:, self.iv], Y[:, self.iz], Y[:, self.ip], Y[:, self.iq]
        if self.nz > 1:
            z = z.reshape(len(Y), self.n, self.nz)
        e = u.f_load + u.k_rope * (r + u.y_load - x - self.delta) + u.c_rope * (rd + u.ydot_load - v)
        T = np.maximum(e, 0.0)
        fr = self.friction.evaluate(v, z, p)
        dp_tap, _ = self.to_tap.dp(q, u.rho, u.mu)
        out = {
            "tension_N": T, "friction_N": fr.F, "z_m": z if self.nz == 1 else self.friction.deflection(z),
            "p_cav_Pa": p, "p_tap_Pa": p - dp_tap, "p_junction_Pa": Y[:, self.ipj],
            "piston_x_m": x, "piston_v_m_s": v, "flow_piston_m3_s": self.A * v, "flow_pipe_m3_s": q,
        }
        if self.nz > 1:
            out["z_elements_m"] = z
        if self.hoist:
            M = u.m_inertia
            acc_rel = (u.m_weight * G - T.sum(axis=1)) / M - u.a_wheel
            out["cage_depth_m"] = u.s_wheel + Y[:, 0]
            out["cage_speed_m_s"] = u.u_wheel + Y[:, 1]
            out["cage_accel_m_s2"] = u.a_wheel + acc_rel
        return out
