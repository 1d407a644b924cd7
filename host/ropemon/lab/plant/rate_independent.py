"""Two rate-independent seal friction laws from the literature, beside `friction`'s four: Dahl and
the second-order Bliman-Sorine. Neither has a velocity Stribeck curve: their friction depends on
the distance slid since the last reversal, not on how fast (only the viscous sigma2(p) v adds a
rate). Same interface as `friction`'s laws (vectorised `evaluate` with the partials the implicit
solvers need, scalar `terms`, `implicit_step` for the test bed, per-rope `force_scale`, pressure
lines in MPa clamped at 0); built from a [plant.friction] table by `friction.from_table`.

- `Dahl` (Dahl 1968, 1976): one state; F rises from rest as Fc (1 - exp(-sigma0 x / Fc)) for
  exponent 1 and saturates at the Coulomb level Fc(p): no break-away above Fc, no velocity
  weakening, reversal curves twice as stiff as the virgin one (exponent 1).
- `BlimanSorine` (Bliman & Sorine 1991, 1995): two Dahl-like states in distance, a fast one that
  rises to f1 and a slow one that takes f2 away again: the break-away peak is a function of the
  distance slid (it comes after ~1-4 eta ef), and its height depends on what came before (largest,
  Fs, after a reversal from long sliding; (Fs + Fc)/2 from an unloaded seal), then F settles to Fc.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ropemon.lab.plant.friction import FrictionOut, Line, _implicit_step, _scaled, _times, settle_states

# Neither law has a Stribeck velocity; the solvers read a `vs` line of every law (unused here).
INERT_VS = Line(1.0, 0.0)


def _pos(p_Pa):
    pos = p_Pa > 0.0
    return np.where(pos, p_Pa, 0.0) * 1e-6, np.where(pos, 1e-6, 0.0)


@dataclass(frozen=True)
class Dahl:
    """Dahl's solid friction (P. R. Dahl, "A solid friction model", Aerospace Corp. TOR-0158(3107-18)-1,
    1968; "Solid friction damping of mechanical vibrations", AIAA J. 14(12), 1976), in the bristle
    form of Olsson, Astrom, Canudas de Wit, Gafvert, Lischinsky, "Friction models and friction
    compensation", Eur. J. Control 4(3), 1998 (dF/dx = sigma0 (1 - F/Fc sgn v)^exponent):

        u      = sgn(v) sigma0 z / Fc(p),   r = 1 - u
        dz/dt  = v sgn(r) |r|^exponent
        F      = sigma0 z + sigma1 dz/dt + sigma2(p) v

    exponent 1: from rest F(x) = Fc (1 - exp(-sigma0 x / Fc)) (the LuGre of Fs = Fc, sigma1 = 0);
    exponent e > 1: F(x) = Fc (1 - (1 + (e - 1) sigma0 x / Fc)^(-1/(e - 1))), a slower approach.
    exponent >= 1 keeps d(dz/dt)/dz bounded (e < 1, Dahl's "brittle" case, reaches Fc at a finite
    x with an infinite slope there). The break-away force is the Coulomb level: `Fs` is Fc's line.
    """

    Fc: Line
    sigma2: Line
    sigma0: float
    exponent: float = 1.0
    sigma1: float = 0.0
    force_scale: tuple[float, ...] | None = None
    name: str = field(default="dahl", init=False)
    n_z = 1

    @property
    def Fs(self) -> Line:
        """No break-away above the Coulomb level: Fc's line (the truth check's bound reads it)."""
        return self.Fc

    @property
    def vs(self) -> Line:
        return INERT_VS

    def _lines(self) -> tuple:
        fc = (self.Fc.intercept, self.Fc.slope)
        return fc + fc + (INERT_VS.intercept, INERT_VS.slope, self.sigma2.intercept, self.sigma2.slope)

    def _pairs(self):
        return ((self.sigma0, 1.0),)

    def _switch1(self, u: float) -> tuple[float, float]:
        """phi(u) = 1 - sgn(1 - u) |1 - u|^exponent, non-decreasing, and dphi/du (`settle_states`)."""
        r = 1.0 - u
        e = self.exponent
        if e == 1.0:
            return u, 1.0
        a = abs(r)
        return 1.0 - math.copysign(a ** e, r), e * a ** (e - 1.0)

    def evaluate(self, v, z, p_Pa) -> FrictionOut:
        p, dpos = _pos(p_Pa)
        fc, gp = self.Fc.at(p), self.Fc.slope
        s0, s1, e = self.sigma0, self.sigma1, self.exponent
        u = np.sign(v) * s0 * z / fc
        r = 1.0 - u
        a = np.abs(r)
        w = np.sign(r) * a ** e if e != 1.0 else r
        dw = -e * a ** (e - 1.0) if e != 1.0 else -np.ones_like(r)   # dw/du
        zdot = v * w
        zd_v = w
        zd_z = np.abs(v) * dw * s0 / fc
        zd_p = -v * dw * u * gp / fc * dpos
        s2 = self.sigma2.at(p)
        F = s0 * z + s1 * zdot + s2 * v
        out = FrictionOut(F, zdot, s1 * zd_v + s2, s0 + s1 * zd_z, s1 * zd_p + self.sigma2.slope * v * dpos,
                          zd_v, zd_z, zd_p)
        return out if self.force_scale is None else _scaled(out, self.force_scale)

    def terms(self, v: float, z: float, pm: float, dpos: float, jac: bool):
        """One rope, scalar, unscaled: (F, dz/dt) and with jac (F_v, F_z, F_p, zd_v, zd_z, zd_p)."""
        fc = self.Fc.intercept + self.Fc.slope * pm
        s0, s1 = self.sigma0, self.sigma1
        sg = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
        u = sg * s0 * z / fc
        phi, D = self._switch1(u)
        w = 1.0 - phi
        s2 = self.sigma2.intercept + self.sigma2.slope * pm
        zd = v * w
        F = s0 * z + s1 * zd + s2 * v
        if not jac:
            return F, zd
        av = v if v >= 0.0 else -v
        zv, zz, zp = w, -av * D * s0 / fc, v * D * u * self.Fc.slope / fc * dpos
        return F, zd, s1 * zv + s2, s0 + s1 * zz, s1 * zp + self.sigma2.slope * v * dpos, zv, zz, zp

    def implicit_step(self, v: float, z: float, pm: float, h: float) -> float:
        """The state after h at constant v and pm (MPa), implicit Euler (the test bed)."""
        return _implicit_step(self, v, (z,), pm, h)[0]

    def solve_states(self, v: float, zh, pm: float, c: float, guess) -> list[float]:
        """z+ of an implicit step's own equation z+ = zh + c v (1 - phi(u+)), solved exactly at the
        step's v and pm (`friction.settle_states`, one state: k = sigma0, alpha = 1, s = Fc(p)), as
        elasto-plastic's: the exponent's curvature is not left to one linearised step."""
        return settle_states(self, v, zh, pm, c, guess)

    def rope_seal(self, i: int | None) -> "Dahl":
        s = 1.0 if i is None or self.force_scale is None else self.force_scale[i]
        return replace(self, Fc=_times(self.Fc, s), sigma2=_times(self.sigma2, s), sigma0=self.sigma0 * s,
                       sigma1=self.sigma1 * s, force_scale=None)


@dataclass(frozen=True)
class BlimanSorine:
    """Second-order Bliman-Sorine friction (P.-A. Bliman, M. Sorine, "Friction modelling by hysteresis
    operators. Application to Dahl, sticktion and Stribeck effects", Proc. Conf. Models of
    Hysteresis, Trento, 1991; "Easy-to-use realistic dry friction models for automatic control",
    Proc. 3rd European Control Conf., Rome, 1995; as in Olsson et al. 1998): in the distance slid
    s (ds = |v| dt), dx/ds = A x + B sgn(v), F = C x with A = diag(-1/(eta ef), -1/ef),
    B = (f1/(eta ef), -f2/ef), C = (1, 1): two first-order (Dahl, exponent 1) elements of lengths
    d1 = eta ef (fast) and d2 = ef (slow), the slow one subtracting. Here in deflections
    z_j = d_j x_j / (+-f_j), with f1 = (Fs + Fc)/2, f2 = (Fs - Fc)/2 of the pressure lines:

        dz_j/dt = v - |v| z_j / d_j                       (j = 1, 2; |z_j| <= d_j)
        F       = f1(p) z1 / d1 - f2(p) z2 / d2 + sigma2(p) v

    Steady sliding: F = f1 - f2 = Fc (+ sigma2 v) at any speed. After a reversal from long sliding
    F(s) = f1 (1 - 2 exp(-s/d1)) - f2 (1 - 2 exp(-s/d2)): up to f1 + f2 = Fs (eta -> 0), then
    back to Fc over ~d2; from an unloaded seal F(s) = f1 (1 - exp(-s/d1)) - f2 (1 - exp(-s/d2)),
    at most f1 = (Fs + Fc)/2. |F| <= Fs(p) + sigma2 |v| always. Both elements are linear in their
    state (LuGre's form with a constant s/sigma0 = d_j), so one linearised implicit step serves
    as for LuGre. The initial stiffness (f1/eta - f2)/ef is positive (f1 > f2, eta < 1).
    """

    Fs: Line
    Fc: Line
    sigma2: Line
    eta: float
    ef: float
    force_scale: tuple[float, ...] | None = None
    name: str = field(default="bliman-sorine", init=False)
    n_z = 2

    @property
    def vs(self) -> Line:
        return INERT_VS

    @property
    def lengths(self) -> tuple[float, float]:
        """(d1, d2) = (eta ef, ef), m."""
        return self.eta * self.ef, self.ef

    def _f12(self, p):
        fs, fc = self.Fs.at(p), self.Fc.at(p)
        return 0.5 * (fs + fc), 0.5 * (fs - fc)

    def evaluate(self, v, z, p_Pa) -> FrictionOut:
        """v, p_Pa of shape S, z of shape S + (2,)."""
        p, dpos = _pos(p_Pa)
        d = np.array(self.lengths)
        f1, f2 = self._f12(p)
        f1p = 0.5 * (self.Fs.slope + self.Fc.slope)
        f2p = 0.5 * (self.Fs.slope - self.Fc.slope)
        v_ = np.asarray(v, dtype=float)[..., None]
        w = z / d
        zdot = v_ - np.abs(v_) * w
        zd_v = 1.0 - np.sign(v_) * w
        zd_z = -np.abs(v_) / d + np.zeros_like(z)
        zd_p = np.zeros_like(z)
        s2 = self.sigma2.at(p)
        F = f1 * w[..., 0] - f2 * w[..., 1] + s2 * v
        F_z = np.stack([f1 / d[0] + np.zeros_like(F), -f2 / d[1] + np.zeros_like(F)], axis=-1)
        F_p = (f1p * w[..., 0] - f2p * w[..., 1] + self.sigma2.slope * v) * dpos
        out = FrictionOut(F, zdot, s2 + np.zeros_like(F), F_z, F_p, zd_v, zd_z, zd_p)
        return out if self.force_scale is None else _scaled(out, self.force_scale)

    def terms(self, v: float, z, pm: float, dpos: float, jac: bool):
        """One rope, scalar, unscaled: (F, [dz_j/dt]) and with jac also (F_v, [F_z_j], F_p, [zd_v_j],
        [zd_z_j], [zd_p_j]); pm in MPa (>= 0), dpos 1e-6 or 0."""
        d1, d2 = self.lengths
        fs, fc = self.Fs.intercept + self.Fs.slope * pm, self.Fc.intercept + self.Fc.slope * pm
        f1, f2 = 0.5 * (fs + fc), 0.5 * (fs - fc)
        z1, z2 = z
        w1, w2 = z1 / d1, z2 / d2
        av = v if v >= 0.0 else -v
        s2 = self.sigma2.intercept + self.sigma2.slope * pm
        F = f1 * w1 - f2 * w2 + s2 * v
        zd = [v - av * w1, v - av * w2]
        if not jac:
            return F, zd
        sg = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
        Fp = (0.5 * (self.Fs.slope + self.Fc.slope) * w1 - 0.5 * (self.Fs.slope - self.Fc.slope) * w2
              + self.sigma2.slope * v) * dpos
        return (F, zd, s2, [f1 / d1, -f2 / d2], Fp, [1.0 - sg * w1, 1.0 - sg * w2], [-av / d1, -av / d2],
                [0.0, 0.0])

    def implicit_step(self, v: float, z, pm: float, h: float) -> list[float]:
        """The two states after h at constant v, implicit Euler, exact for these linear equations:
        z_j+ = (z_j + h v) / (1 + h |v| / d_j) (the test bed)."""
        av = abs(v)
        return [(zj + h * v) / (1.0 + h * av / d) for zj, d in zip(z, self.lengths)]

    def deflection(self, z):
        """The fast element's deflection z1 (m): truth `z_m` (both states go to `z_elements_m`)."""
        return z[..., 0]

    def rope_seal(self, i: int | None) -> "BlimanSorine":
        s = 1.0 if i is None or self.force_scale is None else self.force_scale[i]
        return replace(self, Fs=_times(self.Fs, s), Fc=_times(self.Fc, s), sigma2=_times(self.sigma2, s),
                       force_scale=None)
