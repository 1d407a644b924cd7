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
    m_i v_i' = T_i - p_i A_i - s_i(t) F_i(v_i, z_i, p_i) + E_i(x_i, v_i)
    p_i'  = beta / (V0_i - A_i x_i) * (A_i v_i - q_i - L_i(p_i, t))
    I_i q_i' = o_i(t) (p_i - pj - dp_i(q_i)) - (1 - o_i(t)) I_i q_i / TAU_VALVE_S
    pj'   = beta / Vj * (sum q_i + Q_pump - L_j(pj, t))
    M r'' = M_weight g - sum T_i - M a_wheel          (hoist rig only; a bench rig holds r = 0)

with the equalizer's faults (`Faults`, docs/simulator.md "Faults"): E_i the end stops' one-sided
contact force at x_i = +-stroke_i/2 (`EndStops`), s_i(t) a seized seal's force multiplier (1
otherwise), L the leak flows out of a cavity or the connecting assembly, o_i(t) the open fraction of
rope i's stop valve (1 open, 0 closed: its pipe flow relaxes to 0 within TAU_VALVE_S).

The piston mass m_i (piston and rod) carries inertia only; its weight is part of the
cage, so at rest T_i = p_i A_i + F_i exactly (docs/model.md). The inputs (rope
stiffness as the hanging length changes, loads, payload, pump flow, oil
temperature) are precomputed on the solver's time grid (`Inputs`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

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


END_STOP_STIFFNESS_N_M = 2.0e8    # steel on steel through the piston, rod and end cap, lumped
END_STOP_DAMPING_N_S_M = 2.0e5    # with a 40 kg piston: damping ratio ~1.1 (no bounce off the stop)
TAU_VALVE_S = 1.0e-3              # a closed valve's pipe flow relaxes to 0 with this time constant
SEIZE_RAMP_S = 1.0                # a seal seizing mid-run: its force multiplier rises to the factor over this time
VALVE_CLOSING_S = 0.01            # a valve closing mid-run goes from open to closed over this time
LEAK_KNEE_PA = 0.2e6              # a leak's flow falls linearly to 0 below this gauge pressure


@dataclass(frozen=True)
class EndStops:
    """The cylinders' end stops at x = +-half_stroke_m (x = 0 mid-stroke): a one-sided penalty
    contact, force max(0, k d + c d') against the penetration d, only while d > 0."""

    half_stroke_m: tuple[float, ...]
    stiffness_N_m: float = END_STOP_STIFFNESS_N_M
    damping_N_s_m: float = END_STOP_DAMPING_N_S_M

    def force(self, x, v):
        """(E, dE/dx, dE/dv) on the piston along x, for x, v of shape (..., N)."""
        hs = np.asarray(self.half_stroke_m)
        k, c = self.stiffness_N_m, self.damping_N_s_m
        up = k * (x - hs) + c * v          # pushing back from the extended end
        lo = k * (-hs - x) - c * v         # ... from the retracted end
        on_up = (x > hs) & (up > 0.0)
        on_lo = (x < -hs) & (lo > 0.0)
        E = np.where(on_up, -up, np.where(on_lo, lo, 0.0))
        on = on_up | on_lo
        return E, np.where(on, -k, 0.0), np.where(on, -c, 0.0)


@dataclass(frozen=True)
class Faults:
    """The equalizer's faults as the plant sees them (ropes 0-based; scenario.py builds them from
    [[faults]]). valve_at[i]: time rope i's stop valve is closed (None: open; 0: closed from the
    start); leaks: (where, rate m^3/s, from t) with where a rope or -1 the connecting assembly;
    seize[i]: (from t, force multiplier on the law's output) or None."""

    n: int
    valve_at: tuple = ()
    valve_side: tuple = ()
    leaks: tuple = ()
    seize: tuple = ()
    any: bool = field(init=False, default=False)

    def __post_init__(self):
        if not self.valve_at:
            object.__setattr__(self, "valve_at", (None,) * self.n)
        if not self.valve_side:
            object.__setattr__(self, "valve_side", (None,) * self.n)
        if not self.seize:
            object.__setattr__(self, "seize", (None,) * self.n)
        object.__setattr__(self, "any", bool(self.leaks) or any(a is not None for a in self.valve_at)
                           or any(a is not None for a in self.seize))

    def closed(self, t):
        """Closed fraction 1 - o_i of each rope's valve at times t: shape t.shape + (N,)."""
        t = np.asarray(t, dtype=float)[..., None]
        out = np.zeros(t.shape[:-1] + (self.n,))
        for i, at in enumerate(self.valve_at):
            if at is not None:
                out[..., i] = (t[..., 0] >= 0.0) * 1.0 if at <= 0.0 else np.clip((t[..., 0] - at) / VALVE_CLOSING_S, 0.0, 1.0)
        return out

    def events(self) -> list[float]:
        """Times the faults' inputs change: onsets, and the end of a valve's closing (step points)."""
        ev = [at for at in self.valve_at if at is not None and at > 0.0]
        ev += [at + VALVE_CLOSING_S for at in ev]
        ev += [at for _, _, at in self.leaks if at > 0.0]
        ev += [a for s in self.seize if s is not None and s[0] > 0.0 for a in (s[0], s[0] + SEIZE_RAMP_S)]
        return sorted(set(ev))

    def leak_rates(self, t):
        """Leak rates (m^3/s, before the pressure knee) at times t > the onset: (ropes t.shape + (N,),
        assembly t.shape). From t > at_s, so that over the solver's steps (the onset a step point, the
        leak applied over the steps after it) the leaked volume is rate x (t - at_s)."""
        t = np.asarray(t, dtype=float)
        r = np.zeros(t.shape + (self.n,))
        j = np.zeros(t.shape)
        for where, rate, at in self.leaks:
            on = (t > at) * rate
            if where < 0:
                j = j + on
            else:
                r[..., where] += on
        return r, j

    def seal_mult(self, t, base):
        """Seal force multiplier on the law's output at times t (shape t.shape + (N,)): a seized
        rope's factor over its own force_scale (base), from the start where at_s = 0, else rising
        from 1 to it over SEIZE_RAMP_S after at_s; 1 elsewhere."""
        t = np.asarray(t, dtype=float)[..., None]
        out = np.ones(t.shape[:-1] + (self.n,))
        for i, s in enumerate(self.seize):
            if s is not None:
                at, factor = s
                if at <= 0.0:
                    out[..., i] = np.where(t[..., 0] >= 0.0, factor / base[i], 1.0)
                else:
                    ramp = np.clip((t[..., 0] - at) / SEIZE_RAMP_S, 0.0, 1.0)
                    out[..., i] = 1.0 + (factor / base[i] - 1.0) * ramp
        return out


def leak_flow(rate, p):
    """A leak's flow at gauge pressure p: `rate` above LEAK_KNEE_PA, falling linearly to 0 at p = 0
    (a leak cannot draw a vacuum); and its derivative in p."""
    inside = (p > 0.0) & (p < LEAK_KNEE_PA)
    return rate * np.clip(p / LEAK_KNEE_PA, 0.0, 1.0), np.where(inside, rate / LEAK_KNEE_PA, 0.0)


class Plant:
    def __init__(self, *, area_m2, v0_m3, piston_mass_kg, beta_Pa, junction_volume_m3,
                 to_junction: PathSet, to_tap: PathSet, friction, offsets_m, hoist: bool,
                 end_stops: EndStops | None = None, faults: Faults | None = None):
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
        self.end_stops = end_stops
        self.faults = faults if faults is not None else Faults(n)
        sc = getattr(friction, "force_scale", None)
        self.seal_base = np.ones(n) if sc is None else np.asarray(sc, dtype=float)
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
                 (P, X), (P, V), (P, Q), (Q, P), (Q, PJ), (Q, Q), (PJ, Q), (RD, X), (RD, V), (P, P)]
        rows = [a for a, _ in pairs] + [np.array([0, 1, 1, self.ipj])]
        cols = [b for _, b in pairs] + [np.array([1, 0, 1, self.ipj])]
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
        fa = self.faults
        t = u.t[k]
        if fa.any:
            mult = fa.seal_mult(t, self.seal_base)
            fr.F, fr.F_v, fr.F_p = fr.F * mult, fr.F_v * mult, fr.F_p * mult
            fr.F_z = fr.F_z * (mult if self.nz == 1 else mult[:, None])
            closed = fa.closed(t)
            lr, lj = fa.leak_rates(t)
            QL, dQL = leak_flow(lr, p)
            QLj, dQLj = leak_flow(lj, pj)
        else:
            closed = np.zeros(n)
            QL = dQL = np.zeros(n)
            QLj = dQLj = 0.0
        if self.end_stops is not None:
            E, E_x, E_v = self.end_stops.force(x, v)
        else:
            E = E_x = E_v = np.zeros(n)
        op = 1.0 - closed
        A, m, beta = self.A, self.m, self.beta
        vol = self.V0 - A * x
        rho, mu = u.rho[k], u.mu[k]
        dp, ddp = self.to_junction.dp(q, rho, mu)
        inert = self.to_junction.inertance_per_rho * rho
        f = np.empty(self.size)
        net = A * v - q - QL
        f[self.ix] = v
        f[self.iv] = (T - p * A - fr.F + E) / m
        f[self.iz] = fr.zdot.ravel()
        f[self.ip] = beta / vol * net
        f[self.iq] = op * (p - pj - dp) / inert - closed * q / TAU_VALVE_S
        f[self.ipj] = beta / self.Vj * (q.sum() + u.q_pump[k] - QLj)
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
            ones, hk / m, hc / m, (-hk + E_x) / m, (-hc - fr.F_v + E_v) / m, F_z_m, (-A - fr.F_p) / m,
            fr.zd_v.ravel(), fr.zd_z.ravel(), fr.zd_p.ravel(),
            bv * net * A / vol, bv * A, -bv,
            op / inert, -op / inert, -op * ddp / inert - closed / TAU_VALVE_S,
            (beta / self.Vj) * ones] + cage[:2] + [-bv * dQL, np.append(cage[2], -beta / self.Vj * dQLj)])
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
        pj = Y[:, self.ipj]
        fa = self.faults
        mult = fa.seal_mult(u.t, self.seal_base)
        closed = fa.closed(u.t)
        lr, lj = fa.leak_rates(u.t)
        leak = leak_flow(lr, p)[0].sum(axis=1) + leak_flow(lj, pj)[0]
        p_tap = p - dp_tap
        side = np.array([s == "cylinder" for s in fa.valve_side])
        if side.any():   # a valve between the cylinder and its tap: the tap reads the manifold's side
            p_tap = np.where(side, (1.0 - closed) * p_tap + closed * pj[:, None], p_tap)
        E = self.end_stops.force(x, v)[0] if self.end_stops is not None else np.zeros_like(x)
        out = {
            "tension_N": T, "friction_N": fr.F * mult, "z_m": z if self.nz == 1 else self.friction.deflection(z),
            "p_cav_Pa": p, "p_tap_Pa": p_tap, "p_junction_Pa": pj,
            "piston_x_m": x, "piston_v_m_s": v, "flow_piston_m3_s": self.A * v, "flow_pipe_m3_s": q,
            "end_stop_N": E, "valve_open": 1.0 - closed, "seal_scale": self.seal_base * mult,
            "leak_m3_s": leak,
            # the leak flow over the solver's steps, each step's flow at its end (the implicit steps'
            # own: exact while the flow is constant; first order in the pressure knee)
            "leaked_m3": np.concatenate([[0.0], np.cumsum(leak[1:] * np.diff(u.t))]),
        }
        if self.hoist:
            out["rope_offset_m"] = self.delta - u.y_load
        if self.nz > 1:
            out["z_elements_m"] = z
        if self.hoist:
            M = u.m_inertia
            acc_rel = (u.m_weight * G - T.sum(axis=1)) / M - u.a_wheel
            out["cage_depth_m"] = u.s_wheel + Y[:, 0]
            out["cage_speed_m_s"] = u.u_wheel + Y[:, 1]
            out["cage_accel_m_s2"] = u.a_wheel + acc_rel
        return out
