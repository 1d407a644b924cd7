"""Seal friction laws of the pistons, pluggable: LuGre (default), Coulomb-Stribeck, generalised
Maxwell-slip and elasto-plastic.

Each law gives, vectorised over ropes, the friction force F (sign of the sliding
velocity v, docs/model.md), the rate of its internal state z, and the partial
derivatives the implicit solver needs. Pressures enter in MPa (cavity pressure,
clamped at 0: cavitation is not modelled). Parameters may be per rope.

- `LuGre`: Canudas de Wit et al. 1995 with Fs, Fc, vs, sigma2 linear in pressure,
  the form the node compensates.
- `CoulombStribeck`: a static law like Simscape's cylinder friction,
  F = (Fc + (Fs - Fc) exp(-(v/vs)^2)) tanh(v/v_th) + sigma2 v, with the same
  pressure lines; it has no presliding state, so the node's LuGre compensation
  meets a plant it does not share a model with.
- `MaxwellSlip`: M elastic elements (stiffness k_j) in parallel, each sliding at its
  fraction alpha_j of the Stribeck curve (Lampaert, Al-Bender, Swevers 2003; Al-Bender,
  Lampaert, Swevers, IEEE TAC 2005): pre-sliding hysteresis with memory and corners.
  M states per rope (`n_z`); the stick/slip switch is smoothed (docs/simulator.md).
- `ElastoPlastic`: Dupont, Hayward, Armstrong, Altpeter, IEEE TAC 2002: purely elastic
  below the break-away deflection z_ba, LuGre-like sliding beyond z_ss.

Two rate-independent laws from the literature live beside these in `rate_independent`
(`MORE_LAWS`: Dahl, second-order Bliman-Sorine); `from_table` builds them too.

Every law takes a per-rope `force_scale` (default 1): rope i's force and its partials
are s_i times the law's (Fs, Fc, sigma2 and the stiffnesses scaled alike), the state
dynamics and pre-sliding distances are unchanged.

These laws are the truth and share no code with the product's float seal model
(`ropemon.commission.seal`, which the fit, the float reference and the test bed use) on purpose.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

LINE_KEYS = ("Fs", "Fc", "vs", "sigma2")


@dataclass(frozen=True)
class Line:
    """X(p) = intercept + slope * p_MPa."""

    intercept: float
    slope: float = 0.0

    def at(self, p_mpa):
        return self.intercept + self.slope * p_mpa


@dataclass
class FrictionOut:
    F: np.ndarray
    zdot: np.ndarray
    F_v: np.ndarray
    F_z: np.ndarray
    F_p: np.ndarray      # per Pa
    zd_v: np.ndarray
    zd_z: np.ndarray
    zd_p: np.ndarray     # per Pa


def _g(v, p_mpa, Fs: Line, Fc: Line, vs: Line):
    """Stribeck curve g(v, p) and its partials dg/dv, dg/dp (per MPa)."""
    fs, fc, vss = Fs.at(p_mpa), Fc.at(p_mpa), vs.at(p_mpa)
    e = np.exp(-(v / vss) ** 2)
    g = fc + (fs - fc) * e
    g_v = (fs - fc) * e * (-2.0 * v / (vss * vss))
    g_p = Fc.slope + (Fs.slope - Fc.slope) * e + (fs - fc) * e * (2.0 * v * v / vss ** 3) * vs.slope
    return g, g_v, g_p


@dataclass(frozen=True)
class LuGre:
    Fs: Line
    Fc: Line
    vs: Line
    sigma2: Line
    sigma0: float
    sigma1: float
    force_scale: tuple[float, ...] | None = None
    name: str = field(default="lugre", init=False)
    n_z = 1

    def evaluate(self, v, z, p_Pa) -> FrictionOut:
        pos = p_Pa > 0.0
        p = np.where(pos, p_Pa, 0.0) * 1e-6
        dpos = np.where(pos, 1e-6, 0.0)
        g, g_v, g_p = _g(v, p, self.Fs, self.Fc, self.vs)
        av = np.abs(v)
        s0 = self.sigma0
        zdot = v - s0 * av * z / g
        zd_v = 1.0 - s0 * z * (np.sign(v) * g - av * g_v) / (g * g)
        zd_z = -s0 * av / g
        zd_p = s0 * av * z * g_p / (g * g) * dpos
        s2 = self.sigma2.at(p)
        F = s0 * z + self.sigma1 * zdot + s2 * v
        out = FrictionOut(F, zdot, self.sigma1 * zd_v + s2, s0 + self.sigma1 * zd_z,
                          self.sigma1 * zd_p + self.sigma2.slope * v * dpos, zd_v, zd_z, zd_p)
        return out if self.force_scale is None else _scaled(out, self.force_scale)

    def rope_seal(self, i: int | None) -> "LuGre":
        """Rope i's seal as a law of its own (force_scale folded into the parameters; None: scale 1)."""
        s = 1.0 if i is None or self.force_scale is None else self.force_scale[i]
        return LuGre(Fs=_times(self.Fs, s), Fc=_times(self.Fc, s), vs=self.vs, sigma2=_times(self.sigma2, s),
                     sigma0=self.sigma0 * s, sigma1=self.sigma1 * s)

    def as_fit(self) -> dict:
        """The parameters in the form of `ropemon fit-friction` output (docs/config.md `friction`)."""
        d = {k: {"slope": getattr(self, k).slope, "intercept": getattr(self, k).intercept} for k in LINE_KEYS}
        d["sigma0"] = self.sigma0
        d["sigma1"] = self.sigma1
        return d


@dataclass(frozen=True)
class CoulombStribeck:
    Fs: Line
    Fc: Line
    vs: Line
    sigma2: Line
    v_threshold: float
    force_scale: tuple[float, ...] | None = None
    name: str = field(default="coulomb-stribeck", init=False)
    n_z = 1

    def evaluate(self, v, z, p_Pa) -> FrictionOut:
        pos = p_Pa > 0.0
        p = np.where(pos, p_Pa, 0.0) * 1e-6
        dpos = np.where(pos, 1e-6, 0.0)
        g, g_v, g_p = _g(v, p, self.Fs, self.Fc, self.vs)
        th = np.tanh(v / self.v_threshold)
        s2 = self.sigma2.at(p)
        F = g * th + s2 * v
        F_v = g_v * th + g * (1.0 - th * th) / self.v_threshold + s2
        F_p = (g_p * th + self.sigma2.slope * v) * dpos
        zero = np.zeros_like(F)
        # z is unused: it relaxes to 0 so the state vector keeps one shape for every law.
        out = FrictionOut(F, -z, F_v, zero, F_p, zero, zero - 1.0, zero)
        return out if self.force_scale is None else _scaled(out, self.force_scale)

    def rope_seal(self, i: int | None) -> "CoulombStribeck":
        s = 1.0 if i is None or self.force_scale is None else self.force_scale[i]
        return CoulombStribeck(Fs=_times(self.Fs, s), Fc=_times(self.Fc, s), vs=self.vs,
                               sigma2=_times(self.sigma2, s), v_threshold=self.v_threshold)


def _times(line: Line, s: float) -> Line:
    return line if s == 1.0 else Line(line.intercept * s, line.slope * s)


def _scaled(out: FrictionOut, scale) -> FrictionOut:
    """The force and its partials times the per-rope scale (last axis of F = ropes)."""
    sc = np.asarray(scale, dtype=float)
    sz = sc if out.F_z.ndim == out.F.ndim else sc[:, None]
    return FrictionOut(out.F * sc, out.zdot, out.F_v * sc, out.F_z * sz, out.F_p * sc,
                       out.zd_v, out.zd_z, out.zd_p)


def _g1(v: float, pm: float, fl: tuple) -> tuple[float, float, float]:
    """Scalar Stribeck curve g and dg/dv, dg/dp (per MPa); fl = the four lines' (intercept, slope)."""
    fs0, fs1, fc0, fc1, vs0, vs1 = fl[:6]
    fs, fc, vs = fs0 + fs1 * pm, fc0 + fc1 * pm, vs0 + vs1 * pm
    w = v / vs
    ex = math.exp(-w * w)
    d = (fs - fc) * ex
    return fc + d, d * (-2.0 * v / (vs * vs)), fc1 + (fs1 - fc1) * ex + d * (2.0 * v * v / (vs * vs * vs)) * vs1


LN2 = math.log(2.0)


def _softplus_switch(a):
    """phi = ln(1 + e^a) / ln 2 and dphi/da, overflow-free (numpy)."""
    e = np.exp(-np.abs(a))
    return np.logaddexp(0.0, a) / LN2, np.where(a > 0.0, 1.0, e) / ((1.0 + e) * LN2)


def settle_states(law, v: float, zh, pm: float, c: float, guess=None, tol: float = 1e-13,
                  iters: int = 60) -> list[float]:
    """The states z+ of an implicit step's own equations z_j+ = zh_j + c v (1 - phi(u_j(z_j+))) at a
    given velocity v and pressure pm (MPa), for any law whose states obey dz_j/dt = v (1 - phi(u_j)),
    u_j = sgn(v) z_j / z_max_j, z_max_j = alpha_j s(v, p) / k_j, phi non-decreasing (`law._pairs()`
    gives (k_j, alpha_j), `law._switch1(u)` phi and dphi/du): Maxwell-slip's elements,
    elasto-plastic's one deflection (phi = alpha(u) u, k = sigma0, alpha = 1). zh is the method's
    history (implicit Euler: z; BDF2: a z - b z-), c = beta h.

    The residual z - zh - c v (1 - phi) increases in z (slope >= 1), so the root lies between zh
    and its explicit update zh + c v (1 - phi(zh)): Newton from `guess` (a linear step's value;
    None or outside the bracket: the explicit update), kept inside the bracket by bisection, until
    a step moves z by at most tol z_max. Unscaled: the states do not depend on force_scale."""
    if v == 0.0 or c == 0.0:
        return [float(a) for a in zh]
    g = _g1(v, pm, law._lines())[0]
    sg = 1.0 if v > 0.0 else -1.0
    cv = c * v
    switch = law._switch1
    out = []
    for (K, frac), z0, z in zip(law._pairs(), zh, guess if guess is not None else [None] * len(zh)):
        zmax = frac * g / K
        cu = sg / zmax            # u = cu z
        phi, _ = switch(cu * z0)
        z1 = z0 + cv * (1.0 - phi)
        lo, hi = (z0, z1) if z1 >= z0 else (z1, z0)
        if z is None or not lo <= z <= hi:
            z = z1
        for _ in range(iters):
            phi, d = switch(cu * z)
            G = z - z0 - cv * (1.0 - phi)
            if G < 0.0:
                lo = z
            else:
                hi = z
            zn = z - G / (1.0 + cv * d * cu)
            if not lo <= zn <= hi:
                zn = 0.5 * (lo + hi)
            if abs(zn - z) <= tol * zmax:
                z = zn
                break
            z = zn
        out.append(z)
    return out


def _implicit_step(law, v: float, zs, pm: float, h: float) -> list[float]:
    """Implicit Euler of every state over h at constant v and pressure pm (MPa): z+ = z + h dz/dt(z+)
    (the test bed), by `settle_states`."""
    if v == 0.0 or h == 0.0:
        return list(zs)
    return settle_states(law, v, zs, pm, h, None, 1e-15, 100)


@dataclass(frozen=True)
class MaxwellSlip:
    """Generalised Maxwell-slip seal: M elements in parallel, element j of stiffness k_j
    breaks away at alpha_j s(v, p), s the Stribeck curve of the pressure lines (sum alpha_j = 1).

        u_j    = sgn(v) k_j z_j / (alpha_j s(v, p))
        dz_j/dt = v (1 - phi(u_j)),   phi(u) = ln(1 + exp(n (u - 1))) / ln 2
        F      = sum_j k_j z_j + sigma1 sum_j alpha_j dz_j/dt + sigma2(p) v

    phi is the smoothed stick/slip switch: ~0 in stick (u < 1 - 5/n), 1 at the break (u = 1),
    growing like n (u - 1) / ln 2 beyond, so an element pushed past its break by a solver step
    is pulled back at the rate n |v| k_j / (alpha_j s) with a bounded Jacobian. Each element
    follows the ideal elastic-perfectly-plastic curve min(k_j x, alpha_j s) within 0.85/n of
    alpha_j s (largest at the corner). States: z[..., j], M per rope (`n_z`).
    """

    Fs: Line
    Fc: Line
    vs: Line
    sigma2: Line
    alpha: tuple[float, ...]
    k: tuple[float, ...]
    sharpness: float = 50.0
    sigma1: float = 0.0
    force_scale: tuple[float, ...] | None = None
    name: str = field(default="maxwell-slip", init=False)

    @property
    def n_z(self) -> int:
        return len(self.alpha)

    def _lines(self) -> tuple:
        return (self.Fs.intercept, self.Fs.slope, self.Fc.intercept, self.Fc.slope, self.vs.intercept,
                self.vs.slope, self.sigma2.intercept, self.sigma2.slope)

    def evaluate(self, v, z, p_Pa) -> FrictionOut:
        """v, p_Pa of shape S, z of shape S + (M,)."""
        pos = p_Pa > 0.0
        p = np.where(pos, p_Pa, 0.0) * 1e-6
        dpos = np.where(pos, 1e-6, 0.0)
        g, g_v, g_p = _g(v, p, self.Fs, self.Fc, self.vs)
        al, k, n = np.asarray(self.alpha), np.asarray(self.k), self.sharpness
        v_ = np.asarray(v, dtype=float)[..., None]
        S = al * g[..., None]
        u = np.sign(v_) * k * z / S
        phi, dphi = _softplus_switch(n * (u - 1.0))
        D = n * dphi
        zdot = v_ * (1.0 - phi)
        zd_z = -np.abs(v_) * D * k / S
        vDu = v_ * D * u
        zd_v = 1.0 - phi + vDu * (g_v / g)[..., None]
        zd_p = vDu * (g_p / g * dpos)[..., None]
        s1 = self.sigma1
        s2 = self.sigma2.at(p)
        F = (k * z).sum(axis=-1) + s1 * (al * zdot).sum(axis=-1) + s2 * v
        out = FrictionOut(F, zdot, s1 * (al * zd_v).sum(axis=-1) + s2, k + s1 * al * zd_z,
                          s1 * (al * zd_p).sum(axis=-1) + self.sigma2.slope * v * dpos, zd_v, zd_z, zd_p)
        return out if self.force_scale is None else _scaled(out, self.force_scale)

    def terms(self, v: float, z, pm: float, dpos: float, jac: bool):
        """One rope, scalar (the fast stepper, the test bed), unscaled: (F, [dz_j/dt]) and with jac
        also (F_v, [F_z_j], F_p, [zd_v_j], [zd_z_j], [zd_p_j]); pm in MPa (>= 0), dpos 1e-6 or 0."""
        fl = self._lines()
        g, g_v, g_p = _g1(v, pm, fl)
        s1, switch = self.sigma1, self._switch1
        sg = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
        av = v if v >= 0.0 else -v
        F = (fl[6] + fl[7] * pm) * v
        zd, Fz, zv, zz, zp = [], [], [], [], []
        Fv = Fp = 0.0
        gv, gp = g_v / g, g_p / g * dpos
        for a, kj, zj in zip(self.alpha, self.k, z):
            S = a * g
            u = sg * kj * zj / S
            phi, D = switch(u)
            r = v * (1.0 - phi)
            zd.append(r)
            F += kj * zj + s1 * a * r
            if jac:
                vDu = v * D * u
                dzv, dzz, dzp = 1.0 - phi + vDu * gv, -av * D * kj / S, vDu * gp
                zv.append(dzv)
                zz.append(dzz)
                zp.append(dzp)
                Fz.append(kj + s1 * a * dzz)
                Fv += s1 * a * dzv
                Fp += s1 * a * dzp
        if not jac:
            return F, zd
        return F, zd, Fv + fl[6] + fl[7] * pm, Fz, Fp + fl[7] * v * dpos, zv, zz, zp

    def _pairs(self):
        return tuple(zip(self.k, self.alpha))

    def _switch1(self, u: float) -> tuple[float, float]:
        """Scalar phi(u) and dphi/du."""
        n = self.sharpness
        x = n * (u - 1.0)
        if x > 0.0:
            e = math.exp(-x)
            return (x + math.log1p(e)) / LN2, n / ((1.0 + e) * LN2)
        e = math.exp(x)
        return math.log1p(e) / LN2, n * e / ((1.0 + e) * LN2)

    def implicit_step(self, v: float, z, pm: float, h: float) -> list[float]:
        """The element states after h at constant v and pm (MPa), implicit Euler (the test bed)."""
        return _implicit_step(self, v, z, pm, h)

    def solve_states(self, v: float, zh, pm: float, c: float, guess) -> list[float]:
        """The element states z+ of an implicit step's own equations, solved exactly at the step's
        new velocity v and pressure pm (MPa): z_j+ = zh_j + c v (1 - phi(u_j(z_j+, v, pm))), zh the
        method's history (implicit Euler: z; BDF2: a z - b z-), c = beta h (`settle_states`).

        The plant's BDF2 takes one linearised (Newton) step for the whole state; for an element
        at its break that linearisation is wrong whenever the step reverses v (d(dz/dt)/dv =
        1 - phi < 0 beyond the break, so a reversal would push z further out), which let elements
        run away to hundreds of their break displacements. Each element's equation couples only
        to v and p, so once the linear step has given them, the element's root is found exactly
        (Newton from the linear step's value `guess`, in its bracket); the stepper's
        `_newton_settled` iterates the whole step around it. Returns a list, one per element."""
        return settle_states(self, v, zh, pm, c, guess)

    def deflection(self, z):
        """The elements' elastic force over their total stiffness, sum k_j z_j / sum k_j (m): the
        single deflection per rope recorded as truth `z_m` (the element states go to `z_elements_m`)."""
        k = np.asarray(self.k)
        return (z * k).sum(axis=-1) / k.sum()

    def rope_seal(self, i: int | None) -> "MaxwellSlip":
        s = 1.0 if i is None or self.force_scale is None else self.force_scale[i]
        return replace(self, Fs=_times(self.Fs, s), Fc=_times(self.Fc, s), sigma2=_times(self.sigma2, s),
                       k=tuple(a * s for a in self.k), sigma1=self.sigma1 * s, force_scale=None)


@dataclass(frozen=True)
class ElastoPlastic:
    """Single-state elasto-plastic seal (Dupont, Hayward, Armstrong, Altpeter, IEEE TAC 2002):

        z_ss   = s(v, p) / sigma0,  u = sgn(v) z / z_ss,  beta = z_ba / z_ss (`z_ba_fraction`)
        alpha  = 0 for u <= beta (elastic; also whenever z and v differ in sign),
                 1/2 + 1/2 sin(pi ((u - beta) / (1 - beta) - 1/2)) for beta < u < 1,  1 for u >= 1
        dz/dt  = v (1 - alpha u)
        F      = sigma0 z + sigma1 dz/dt + sigma2(p) v

    Below the break-away deflection z_ba = beta z_ss the seal is a pure spring (an oscillation
    there returns z exactly: no drift); beyond z_ss it is LuGre. alpha is C1 in u.
    """

    Fs: Line
    Fc: Line
    vs: Line
    sigma2: Line
    sigma0: float
    sigma1: float
    z_ba_fraction: float
    force_scale: tuple[float, ...] | None = None
    name: str = field(default="elasto-plastic", init=False)
    n_z = 1

    def _lines(self) -> tuple:
        return (self.Fs.intercept, self.Fs.slope, self.Fc.intercept, self.Fc.slope, self.vs.intercept,
                self.vs.slope, self.sigma2.intercept, self.sigma2.slope)

    def _pairs(self):
        return ((self.sigma0, 1.0),)

    def _switch1(self, u: float) -> tuple[float, float]:
        """Scalar phi = alpha(u) u and dphi/du."""
        b = self.z_ba_fraction
        if u <= b:
            return 0.0, 0.0
        if u >= 1.0:
            return u, 1.0
        arg = math.pi * ((u - b) / (1.0 - b) - 0.5)
        al = 0.5 + 0.5 * math.sin(arg)
        return al * u, al + u * 0.5 * math.pi / (1.0 - b) * math.cos(arg)

    def implicit_step(self, v: float, z: float, pm: float, h: float) -> float:
        """The state after h at constant v and pm (MPa), implicit Euler (the test bed)."""
        return _implicit_step(self, v, (z,), pm, h)[0]

    def solve_states(self, v: float, zh, pm: float, c: float, guess) -> list[float]:
        """The deflection z+ of an implicit step's own equation z+ = zh + c v (1 - alpha(u+) u+),
        solved exactly at the step's new velocity v and pressure pm (MPa) (`settle_states`, one
        state: k = sigma0, alpha = 1); zh, guess and the result are sequences of one.

        As Maxwell-slip's elements: beyond z_ss (u > 1), d(dz/dt)/dv = 1 - u < 0, so one linearised
        step that reverses v pushed z further out instead of back along the spring (population-148:
        z to 257 z_ss, the seal friction to 299 Fs, the oil pressure to -20 MPa); the stepper's
        `_newton_settled` solves the step with this row settled exactly."""
        return settle_states(self, v, zh, pm, c, guess)

    def _switch(self, u):
        """phi = alpha(u) u and dphi/du (numpy)."""
        b = self.z_ba_fraction
        xi = np.clip((u - b) / (1.0 - b), 0.0, 1.0)
        arg = np.pi * (xi - 0.5)
        inside = (u > b) & (u < 1.0)
        al = np.where(u >= 1.0, 1.0, np.where(inside, 0.5 + 0.5 * np.sin(arg), 0.0))
        dal = np.where(inside, 0.5 * np.pi / (1.0 - b) * np.cos(arg), 0.0)
        return al * u, al + u * dal

    def evaluate(self, v, z, p_Pa) -> FrictionOut:
        pos = p_Pa > 0.0
        p = np.where(pos, p_Pa, 0.0) * 1e-6
        dpos = np.where(pos, 1e-6, 0.0)
        g, g_v, g_p = _g(v, p, self.Fs, self.Fc, self.vs)
        s0, s1 = self.sigma0, self.sigma1
        u = np.sign(v) * s0 * z / g
        phi, D = self._switch(u)
        zdot = v * (1.0 - phi)
        vDu = v * D * u
        zd_v = 1.0 - phi + vDu * g_v / g
        zd_z = -np.abs(v) * D * s0 / g
        zd_p = vDu * g_p / g * dpos
        s2 = self.sigma2.at(p)
        F = s0 * z + s1 * zdot + s2 * v
        out = FrictionOut(F, zdot, s1 * zd_v + s2, s0 + s1 * zd_z, s1 * zd_p + self.sigma2.slope * v * dpos,
                          zd_v, zd_z, zd_p)
        return out if self.force_scale is None else _scaled(out, self.force_scale)

    def terms(self, v: float, z: float, pm: float, dpos: float, jac: bool):
        """One rope, scalar, unscaled: (F, dz/dt) and with jac (F_v, F_z, F_p, zd_v, zd_z, zd_p)."""
        fl = (self.Fs.intercept, self.Fs.slope, self.Fc.intercept, self.Fc.slope, self.vs.intercept,
              self.vs.slope)
        g, g_v, g_p = _g1(v, pm, fl)
        s0, s1 = self.sigma0, self.sigma1
        sg = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
        u = sg * s0 * z / g
        phi, D = self._switch1(u)
        s2 = self.sigma2.intercept + self.sigma2.slope * pm
        zd = v * (1.0 - phi)
        F = s0 * z + s1 * zd + s2 * v
        if not jac:
            return F, zd
        vDu = v * D * u
        av = v if v >= 0.0 else -v
        zv, zz, zp = 1.0 - phi + vDu * g_v / g, -av * D * s0 / g, vDu * g_p / g * dpos
        return F, zd, s1 * zv + s2, s0 + s1 * zz, s1 * zp + self.sigma2.slope * v * dpos, zv, zz, zp

    def rope_seal(self, i: int | None) -> "ElastoPlastic":
        s = 1.0 if i is None or self.force_scale is None else self.force_scale[i]
        return replace(self, Fs=_times(self.Fs, s), Fc=_times(self.Fc, s), sigma2=_times(self.sigma2, s),
                       sigma0=self.sigma0 * s, sigma1=self.sigma1 * s, force_scale=None)


LAWS = ("lugre", "coulomb-stribeck", "maxwell-slip", "elasto-plastic")
# rate_independent.py's laws: built by from_table, not yet run by the fast stepper (stepper.Stepper)
MORE_LAWS = ("dahl", "bliman-sorine")
ALL_LAWS = LAWS + MORE_LAWS
# the pressure lines each law reads (the others: all of LINE_KEYS)
LAW_LINES = {"dahl": ("Fc", "sigma2"), "bliman-sorine": ("Fs", "Fc", "sigma2")}


def example_table(law: str) -> dict:
    """A [plant.friction] table of `law` (one of ALL_LAWS) with the magnitudes of paper-field-trip's
    LuGre seal: Fs = 2500 + 2000 p, Fc = 1700 + 1200 p (N, p in MPa), vs = 4 - 0.1 p mm/s,
    sigma2 = 20000 + 2000 p N s/m, pre-sliding over ~80 um at 8 kN (Maxwell-slip: elements
    breaking at 10, 30, 60 and 120 um at s = 8 kN; Dahl: sigma0 as LuGre's, exponent 1;
    Bliman-Sorine: lengths 40 and 400 um). Laws without a Stribeck velocity (Dahl, Bliman-Sorine)
    or a static level (Dahl) have only the lines they read (`LAW_LINES`). A fresh dict: perturb
    it freely."""
    if law not in ALL_LAWS:
        raise ValueError(f"law: must be one of {ALL_LAWS}, got {law!r}")
    t: dict = {"law": law, "Fs": {"intercept": 2500.0, "slope": 2000.0},
               "Fc": {"intercept": 1700.0, "slope": 1200.0}, "vs": {"intercept": 0.004, "slope": -0.0001},
               "sigma2": {"intercept": 20000.0, "slope": 2000.0}}
    for k in set(LINE_KEYS) - set(LAW_LINES.get(law, LINE_KEYS)):
        del t[k]
    if law == "lugre":
        t.update(sigma0=1.0e8, sigma1=5.0e4)
    elif law == "coulomb-stribeck":
        t.update(v_threshold=1.0e-4)
    elif law == "maxwell-slip":
        alpha = [0.1, 0.2, 0.3, 0.4]
        t.update(alpha=alpha, k=[a * 8000.0 / d for a, d in zip(alpha, (10e-6, 30e-6, 60e-6, 120e-6))],
                 sharpness=50.0, sigma1=5.0e4)
    elif law == "elasto-plastic":
        t.update(sigma0=1.0e8, sigma1=5.0e4, z_ba_fraction=0.4)
    elif law == "dahl":
        t.update(sigma0=1.0e8, exponent=1.0)
    elif law == "bliman-sorine":
        t.update(eta=0.1, ef=4.0e-4)
    return t


def _numbers(t: dict, key: str, where: str, *, gt=None, length: int | None = None) -> tuple[float, ...]:
    from ropemon.station import tomlfields
    from ropemon.lab.plant.scenario import ScenarioError

    v = t.get(key)
    if not isinstance(v, list) or not v:
        raise ScenarioError(f"{where}.{key}: missing, or not a non-empty list of numbers")
    if length is not None and len(v) != length:
        raise ScenarioError(f"{where}.{key}: must have {length} values, got {len(v)}")
    return tuple(tomlfields.check_number(x, f"{where}.{key}[{i}]", ScenarioError, gt=gt) for i, x in enumerate(v))


def from_table(t: dict, where: str, n_ropes: int | None = None):
    """Build a law from a scenario's [plant.friction] table; errors name the field.

    n_ropes, when given, is the length `force_scale` must have."""
    from ropemon.lab.plant.scenario import ScenarioError, number

    law = t.get("law", "lugre")
    if law not in ALL_LAWS:
        raise ScenarioError(f"{where}.law: must be one of {', '.join(repr(a) for a in ALL_LAWS)}, got {law!r}")
    keys = LAW_LINES.get(law, LINE_KEYS)
    lines = {}
    for k in keys:
        v = t.get(k)
        if not isinstance(v, dict):
            raise ScenarioError(f"{where}.{k}: missing, or not a table {{intercept = ..., slope = ...}}")
        unknown = set(v) - {"intercept", "slope"}
        if unknown:
            raise ScenarioError(f"{where}.{k}.{sorted(unknown)[0]}: unknown field")
        lines[k] = Line(number(v, "intercept", f"{where}.{k}"), number(v, "slope", f"{where}.{k}", default=0.0))
    if "vs" in lines and lines["vs"].intercept <= 0:
        raise ScenarioError(f"{where}.vs.intercept: must be > 0")
    scale = None
    if "force_scale" in t:
        if not isinstance(t["force_scale"], list) or (n_ropes is not None and len(t["force_scale"]) != n_ropes):
            raise ScenarioError(f"{where}.force_scale: must be a list of one number per rope"
                                + (f" ({n_ropes})" if n_ropes is not None else ""))
        scale = _numbers(t, "force_scale", where, gt=0)
    common = {"law", *keys, "force_scale"}
    if law == "lugre":
        extra = common | {"sigma0", "sigma1"}
        f = LuGre(**lines, sigma0=number(t, "sigma0", where, gt=0), sigma1=number(t, "sigma1", where, ge=0),
                  force_scale=scale)
    elif law == "coulomb-stribeck":
        extra = common | {"v_threshold"}
        f = CoulombStribeck(**lines, v_threshold=number(t, "v_threshold", where, gt=0), force_scale=scale)
    elif law == "maxwell-slip":
        extra = common | {"alpha", "k", "sharpness", "sigma1"}
        alpha = _numbers(t, "alpha", where, gt=0)
        if len(alpha) > 16:
            raise ScenarioError(f"{where}.alpha: at most 16 elements, got {len(alpha)}")
        if abs(sum(alpha) - 1.0) > 1e-6:
            raise ScenarioError(f"{where}.alpha: the fractions must sum to 1, got {sum(alpha):.9g}")
        f = MaxwellSlip(**lines, alpha=alpha, k=_numbers(t, "k", where, gt=0, length=len(alpha)),
                        sharpness=number(t, "sharpness", where, 50.0, ge=4, le=1000),
                        sigma1=number(t, "sigma1", where, 0.0, ge=0), force_scale=scale)
    elif law == "elasto-plastic":
        extra = common | {"sigma0", "sigma1", "z_ba_fraction"}
        f = ElastoPlastic(**lines, sigma0=number(t, "sigma0", where, gt=0), sigma1=number(t, "sigma1", where, ge=0),
                          z_ba_fraction=number(t, "z_ba_fraction", where, ge=0, lt=1), force_scale=scale)
    elif law == "dahl":
        from ropemon.lab.plant.rate_independent import Dahl

        if lines["Fc"].intercept <= 0:
            raise ScenarioError(f"{where}.Fc.intercept: must be > 0")
        extra = common | {"sigma0", "sigma1", "exponent"}
        f = Dahl(**lines, sigma0=number(t, "sigma0", where, gt=0),
                 exponent=number(t, "exponent", where, 1.0, ge=1, le=4),
                 sigma1=number(t, "sigma1", where, 0.0, ge=0), force_scale=scale)
    else:  # bliman-sorine
        from ropemon.lab.plant.rate_independent import BlimanSorine

        extra = common | {"eta", "ef"}
        f = BlimanSorine(**lines, eta=number(t, "eta", where, gt=0, lt=1), ef=number(t, "ef", where, gt=0),
                         force_scale=scale)
    unknown = set(t) - extra
    if unknown:
        raise ScenarioError(f"{where}.{sorted(unknown)[0]}: unknown field for law {law!r}")
    return f
