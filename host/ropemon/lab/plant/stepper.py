"""The plant's equations as a scalar-Python BDF2 (or ROS2) stepper that exploits their structure.

Same equations, same methods as `model.Plant.rhs` + `solver.integrate` (tests check the
right-hand side, the Jacobian and whole runs against the numpy model), but
written for speed: with 4 ropes, numpy's per-call overhead on 4-element arrays
dominates, so here everything is Python floats, and the linear system of each
step, W = I - gamma h J, is solved by block elimination instead of a dense
inverse. Per rope, the x, z and q rows are eliminated into a 2x2 system in (v, p)
(a law with M states per rope, Maxwell-slip, has M z rows, each coupled only to v, its
own z and p, so each eliminates like a single z); its solution is affine in the three shared unknowns (cage r, rd and junction
pressure pj), which a 3x3 system gives. W's factors are built once per step (ROS2:
they serve both stages).

Its seal friction (the Stribeck curve, the pressure lines) is its own, not the product's
float seal model (`ropemon.commission.seal`): the simulator is the truth and shares no code
with what it tests, on purpose.
"""
from __future__ import annotations

import math

import numpy as np

from ropemon.lab.plant.friction import CoulombStribeck, ElastoPlastic, LuGre, MaxwellSlip
from ropemon.lab.plant.model import G, LEAK_KNEE_PA, TAU_VALVE_S
from ropemon.lab.plant.rate_independent import BlimanSorine, Dahl
from ropemon.lab.plant.solver import GAMMA


METHODS = ("bdf2", "ros2")


class Stepper:
    def __init__(self, plant, u):
        self.plant = plant
        n = self.n = plant.n
        self.A = [float(a) for a in plant.A]
        self.V0 = [float(a) for a in plant.V0]
        self.m = [float(a) for a in plant.m]
        self.beta = plant.beta
        self.bVj = plant.beta / plant.Vj
        self.delta = [float(a) for a in plant.delta]
        self.hoist = plant.hoist
        fr = plant.friction
        self.nz = plant.nz
        self.lugre = isinstance(fr, LuGre)
        # 0: LuGre, 1: Coulomb-Stribeck (both inline), 2: a law's own scalar `terms` per rope
        self.kind = 0 if self.lugre else 1 if isinstance(fr, CoulombStribeck) else 2
        if self.kind == 2 and not isinstance(fr, (MaxwellSlip, ElastoPlastic, Dahl, BlimanSorine)):
            raise TypeError(f"no fast stepper for friction law {type(fr).__name__}")
        self.terms = fr.terms if self.kind == 2 else None
        self.scale = None if fr.force_scale is None else [float(a) for a in fr.force_scale]
        if self.nz > 1:
            self.factor, self.solve = self._factor_multi, self._solve_multi
        # a law whose states are each solved exactly inside the implicit step (Maxwell-slip,
        # elasto-plastic: `solve_states`) has its BDF2 steps solved by `_newton_settled`
        self.solve_states = getattr(fr, "solve_states", None)
        self.fl = tuple(float(v) for v in (fr.Fs.intercept, fr.Fs.slope, fr.Fc.intercept, fr.Fc.slope,
                                           fr.vs.intercept, fr.vs.slope, fr.sigma2.intercept, fr.sigma2.slope))
        self.s0 = float(fr.sigma0) if self.lugre else 0.0
        self.s1 = float(fr.sigma1) if self.lugre else 0.0
        self.vth = float(fr.v_threshold) if self.kind == 1 else 0.0
        ps = plant.to_junction
        # per rope: laminar coefficients (x mu) and Blasius coefficients (x rho^.75 mu^.25) of its segments
        self.seg = [[] for _ in range(n)]
        for i, L, d, a in zip(ps.s_idx, ps.s_L, ps.s_d, ps.s_a):
            self.seg[int(i)].append((32.0 * L / (d * d * a), 0.3164 * L / (2.0 * d ** 1.25 * a ** 1.75)))
        # a segment turns Blasius when cb rho^.75 mu^.25 |q|^.75 > mu cl, i.e. |q| > (cl/cb)^(4/3) nu;
        # below the smallest such flow of a rope all its segments are laminar
        self.seg_lam_sum = [sum(cl for cl, _ in segs) for segs in self.seg]
        self.seg_q_turb = [min((cl / cb) ** (4.0 / 3.0) for cl, cb in segs) for segs in self.seg]
        self.lin_loc = [float(a) for a in ps.lin_loc]
        self.rope = [(self.A[i], self.m[i], self.delta[i], self.V0[i], self.seg_q_turb[i], self.seg_lam_sum[i],
                      self.lin_loc[i], float(ps.quad_per_rho[i]), float(ps.inertance_per_rho[i]), tuple(self.seg[i]),
                      1.0 if self.scale is None else self.scale[i])
                     for i in range(n)]
        self.quad = [float(a) for a in ps.quad_per_rho]
        self.inert_per_rho = [float(a) for a in ps.inertance_per_rho]
        # end stops: half strokes, contact stiffness and damping (inf: none)
        es = plant.end_stops
        self.half = [float(a) for a in es.half_stroke_m] if es is not None else [math.inf] * n
        self.kes = float(es.stiffness_N_m) if es is not None else 0.0
        self.ces = float(es.damping_N_s_m) if es is not None else 0.0
        # faults (time-dependent): valve open fractions, leak rates, seal scales per step
        self.faults = plant.faults if plant.faults.any else None
        self.base = [1.0] * n if self.scale is None else list(self.scale)
        # per rope, its constants and then (seal scale, half stroke, valve open fraction, leak rate):
        # the last two change with the faults (`fault_state`)
        self.rope = [r[:-1] + (self.base[i], self.half[i], 1.0, 0.0) for i, r in enumerate(self.rope)]
        self._ft, self._fs, self._fkey = None, None, None
        self.touched = False
        self.set_inputs(u)

    def contacts(self, y) -> tuple:
        """Each rope's end-stop contact at state y: 1 at the extended end, -1 the retracted, 0 none."""
        n, kes, ces = self.n, self.kes, self.ces
        out = []
        for x, v, half in zip(y[2:2 + n], y[2 + n:2 + 2 * n], self.half):
            if x > half and kes * (x - half) + ces * v > 0.0:
                out.append(1)
            elif x < -half and kes * (-half - x) - ces * v > 0.0:
                out.append(-1)
            else:
                out.append(0)
        return tuple(out)

    def fault_state(self, t: float):
        """(the rope tuples with their seal scales, valve open fractions and leak rates at time t,
        the assembly's leak rate m^3/s)."""
        fa = self.faults
        if t == self._ft:
            return self._fs
        op = [1.0 - float(c) for c in fa.closed(t)]
        lr, lj = fa.leak_rates(t)
        sc = [b * float(mm) for b, mm in zip(self.base, fa.seal_mult(t, self.plant.seal_base))]
        key = (tuple(op), tuple(float(a) for a in lr), float(lj), tuple(sc))
        if key != self._fkey:
            self._fkey = key
            self._frope = [r[:-4] + (a, r[-3], b, c) for r, a, b, c in zip(self.rope, sc, op, key[1])]
        self._ft, self._fs = t, (self._frope, key[2])
        return self._fs

    def set_inputs(self, u) -> None:
        """Inputs as Python lists (indexing numpy rows per step is slow); k indexes u's rows."""
        self.kr = u.k_rope.tolist()
        self.cr = u.c_rope.tolist()
        self.fload = u.f_load.tolist()
        self.yl = u.y_load.tolist()
        self.ydl = u.ydot_load.tolist()
        self.aw = u.a_wheel.tolist()
        self.mw = u.m_weight.tolist()
        self.mi = u.m_inertia.tolist()
        self.qp = u.q_pump.tolist()
        self.rho = u.rho.tolist()
        self.mu = u.mu.tolist()
        self.t = u.t.tolist()

    def settle(self, y, zh, c) -> None:
        """Replace the friction rows of an implicit step's result y (in place) by the exact roots
        of their own equations z+ = zh + c f_z(v+, z+, p+) at the step's v+ and p+ (the law's
        `solve_states`: Maxwell-slip, elasto-plastic); zh = the method's history of those rows."""
        settle_rows(self.solve_states, self.n, self.nz, y, zh, c)

    # ------------------------------------------------------------------ right-hand side

    def rhs(self, k, y, jac=False):
        """f(t_k, y) as a flat list in the model's state order; with jac, also the Jacobian entries."""
        n = self.n
        r, rd = y[0], y[1]
        kr, cr, fl, yl, ydl = self.kr[k], self.cr[k], self.fload[k], self.yl[k], self.ydl[k]
        rho, mu = self.rho[k], self.mu[k]
        exp, tanh = math.exp, math.tanh
        bl_scale = rho ** 0.75 * mu ** 0.25
        nu = mu / rho
        fs0, fs1, fc0, fc1, vs0, vs1, s20, s21 = self.fl
        s0, s1, vth, kind, terms = self.s0, self.s1, self.vth, self.kind, self.terms
        ropes, lj = self.fault_state(self.t[k]) if self.faults is not None else (self.rope, 0.0)
        scaled = self.scale is not None or self.faults is not None
        kes, ces = self.kes, self.ces
        beta = self.beta
        nz = self.nz
        o = 2 + 2 * n + n * nz    # first pressure
        pj = y[o + 2 * n]
        zs = y[2 + 2 * n:o] if nz == 1 else [y[2 + 2 * n + i * nz:2 + 2 * n + (i + 1) * nz] for i in range(n)]
        fx, fv, fz, fp, fq = [], [], [], [], []
        touched = False
        sumT = 0.0
        sumq = 0.0
        J = [] if jac else None
        shk = shc = 0.0
        for (A, m, delta, V0, q_turb, lam_sum, lin_loc, quad, inert_pr, seg, sc, half, op, lr), x, v, z, p, q, kri, \
                cri, fli, yli, ydli in zip(ropes, y[2:2 + n], y[2 + n:2 + 2 * n], zs, y[o:o + n], y[o + n:o + 2 * n],
                                           kr, cr, fl, yl, ydl):
            e = fli + kri * (r + yli - x - delta) + cri * (rd + ydli - v)
            if e > 0.0:
                T, hk, hc = e, kri, cri
            else:
                T, hk, hc = 0.0, 0.0, 0.0
            sumT += T
            # friction
            if p > 0.0:
                pm, dpos = p * 1e-6, 1e-6
            else:
                pm, dpos = 0.0, 0.0
            if kind == 2:
                res = terms(v, z, pm, dpos, jac)
                F, zdot = res[0], res[1]
            else:
                fs, fc, vs = fs0 + fs1 * pm, fc0 + fc1 * pm, vs0 + vs1 * pm
                s2 = s20 + s21 * pm
                w = v / vs
                ex = exp(-w * w)
                g = fc + (fs - fc) * ex
                av = v if v >= 0.0 else -v
                if kind == 0:
                    zdot = v - s0 * av * z / g
                    F = s0 * z + s1 * zdot + s2 * v
                else:
                    th = tanh(v / vth)
                    zdot = -z
                    F = g * th + s2 * v
            if scaled:
                F *= sc
            # pipe to the junction
            aq = q if q >= 0.0 else -q
            if aq <= q_turb * nu:
                # every segment laminar (the usual case): no fractional power needed
                lam = mu * lam_sum
                dp = lam * q
                ddp = lam
            else:
                aq75 = aq ** 0.75
                dp = 0.0
                ddp = 0.0
                for cl, cb in seg:
                    lam = mu * cl
                    bla = cb * bl_scale * aq75
                    if bla > lam:
                        dp += bla * q
                        ddp += 1.75 * bla
                    else:
                        dp += lam * q
                        ddp += lam
            ll = mu * lin_loc
            qd = quad * rho
            dp += ll * q + qd * q * aq
            ddp += ll + 2.0 * qd * aq
            inert = inert_pr * rho
            vol = V0 - A * x
            bv = beta / vol
            # end stops: one-sided penalty contact while penetrating
            E = ek = ec = 0.0
            if not -half <= x <= half:
                touched = True
                if x > half:
                    fe = kes * (x - half) + ces * v
                    if fe > 0.0:
                        E, ek, ec = -fe, kes, ces
                else:
                    fe = kes * (-half - x) - ces * v
                    if fe > 0.0:
                        E, ek, ec = fe, kes, ces
            # a leak out of the cavity
            if lr:
                if p >= LEAK_KNEE_PA:
                    QL, dQL = lr, 0.0
                elif p > 0.0:
                    QL, dQL = lr * p / LEAK_KNEE_PA, lr / LEAK_KNEE_PA
                else:
                    QL = dQL = 0.0
                net = A * v - q - QL
            else:
                dQL = 0.0
                net = A * v - q
            fx.append(v)
            fv.append((T - p * A - F + E) / m)
            if nz == 1:
                fz.append(zdot)
            else:
                fz.extend(zdot)
            fp.append(bv * net)
            if op == 1.0:
                fq.append((p - pj - dp) / inert)
            else:
                fq.append(op * (p - pj - dp) / inert - (1.0 - op) * q / TAU_VALVE_S)
            sumq += q
            if jac:
                if kind == 2:
                    F_v, F_z, F_p, zd_v, zd_z, zd_p = res[2:]
                    if nz > 1:   # F_z per element, here already over m and scaled
                        F_z = [sc * a / m for a in F_z] if scaled else [a / m for a in F_z]
                        zd_v, zd_z, zd_p = tuple(zd_v), tuple(zd_z), tuple(zd_p)
                elif kind == 0:
                    g_v = (fs - fc) * ex * (-2.0 * v / (vs * vs))
                    g_p = fc1 + (fs1 - fc1) * ex + (fs - fc) * ex * (2.0 * v * v / (vs * vs * vs)) * vs1
                    sg = 1.0 if v > 0 else (-1.0 if v < 0 else 0.0)
                    zd_v = 1.0 - s0 * z * (sg * g - av * g_v) / (g * g)
                    zd_z = -s0 * av / g
                    zd_p = s0 * av * z * g_p / (g * g) * dpos
                    F_v = s1 * zd_v + s2
                    F_z = s0 + s1 * zd_z
                    F_p = s1 * zd_p + s21 * v * dpos
                else:
                    g_v = (fs - fc) * ex * (-2.0 * v / (vs * vs))
                    g_p = fc1 + (fs1 - fc1) * ex + (fs - fc) * ex * (2.0 * v * v / (vs * vs * vs)) * vs1
                    zd_v, zd_z, zd_p = 0.0, -1.0, 0.0
                    F_v = g_v * th + g * (1.0 - th * th) / vth + s2
                    F_z = 0.0
                    F_p = (g_p * th + s21 * v) * dpos
                if scaled:
                    F_v *= sc
                    F_p *= sc
                    if nz == 1:
                        F_z *= sc
                shk += hk
                shc += hc
                if op == 1.0:
                    jqp, jqpj, jqq = 1.0 / inert, -1.0 / inert, -ddp / inert
                else:
                    jqp, jqpj, jqq = op / inert, -op / inert, -op * ddp / inert - (1.0 - op) / TAU_VALVE_S
                J.append((hk / m, hc / m, (-hk - ek) / m, (-hc - F_v - ec) / m,
                          -F_z / m if nz == 1 else tuple(-a for a in F_z), (-A - F_p) / m,
                          zd_v, zd_z, zd_p, bv * net * A / vol, bv * A, -bv,
                          jqp, jqpj, jqq, hk, hc, -bv * dQL))
        if self.hoist:
            M = self.mi[k]
            f0, f1 = rd, (self.mw[k] * G - sumT) / M - self.aw[k]
        else:
            M = 1.0
            f0 = f1 = 0.0
        self.touched = touched     # some piston beyond its stroke at y (`integrate_fast` checks contacts)
        jjj = 0.0
        if lj:   # a leak out of the connecting assembly
            if pj >= LEAK_KNEE_PA:
                sumq -= lj
            elif pj > 0.0:
                sumq -= lj * pj / LEAK_KNEE_PA
                jjj = -self.bVj * lj / LEAK_KNEE_PA
        f = [f0, f1] + fx + fv + fz + fp + fq + [self.bVj * (sumq + self.qp[k])]
        if not jac:
            return f
        cage = (1.0 / M, -shk / M, -shc / M) if self.hoist else None
        return f, (J, cage, jjj)

    # ------------------------------------------------------------------ linear solve

    def factor(self, jac, c):
        """Coefficients of the block elimination of W = I - c J (c = gamma h)."""
        rows, cage, jjj = jac
        cc = c * c
        per1, per2 = [], []
        # sums for the 3x3 system
        m10 = m11 = m12 = 0.0
        m20 = m21 = m22 = 0.0
        hoist = cage is not None
        if hoist:
            invM, jrdr, jrdrd = cage
        for (jvr, jvrd, jvx, jvv, jvz, jvp, jzv, jzz, jzp, jpx, jpv, jpq, jqp, jqpj, jqq, hk, hc, jpp) in rows:
            dz = 1.0 / (1.0 - c * jzz)
            dq = 1.0 / (1.0 - c * jqq)
            a11 = 1.0 - c * jvv - cc * jvx - cc * jvz * jzv * dz
            a12 = -c * jvp - cc * jvz * jzp * dz
            a21 = -c * jpv - cc * jpx
            a22 = 1.0 - c * jpp - cc * jpq * jqp * dq
            det = a11 * a22 - a12 * a21
            i11, i12, i21, i22 = a22 / det, -a12 / det, -a21 / det, a11 / det
            e1r, e1rd, e2pj = c * jvr, c * jvrd, cc * jpq * dq * jqpj
            Vr, Vrd, Vpj = i11 * e1r, i11 * e1rd, i12 * e2pj
            Pr, Prd, Ppj = i21 * e1r, i21 * e1rd, i22 * e2pj
            cq = dq * c * jqp
            Qr, Qrd, Qpj = cq * Pr, cq * Prd, cq * Ppj + dq * c * jqpj
            jrdx = hk * invM if hoist else 0.0
            w = (c * hk + hc) * invM if hoist else 0.0   # c jrdx + jrdv
            m10 += w * Vr
            m11 += w * Vrd
            m12 += w * Vpj
            m20 += Qr
            m21 += Qrd
            m22 += Qpj
            per1.append((dq, i11, i12, i21, i22, c * jvx, c * jvz * dz, c * jpx, c * jpq * dq, cq, w, jrdx))
            per2.append((dz, dq, cq, Vr, Vrd, Vpj, Pr, Prd, Ppj, c * jzv, c * jzp, dq * c * jqpj))
        cb = c * self.bVj
        if hoist:
            a = ((1.0, -c, 0.0),
                 (-c * jrdr - c * m10, 1.0 - c * jrdrd - c * m11, -c * m12),
                 (-cb * m20, -cb * m21, 1.0 - cb * m22 - c * jjj))
        else:
            a = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (-cb * m20, -cb * m21, 1.0 - cb * m22 - c * jjj))
        return per1, per2, _inv3(a), c, cb

    def solve(self, fac, b):
        per1, per2, ai, c, cb = fac
        n = self.n
        bx, bv, bz, bp, bq = b[2:2 + n], b[2 + n:2 + 2 * n], b[2 + 2 * n:2 + 3 * n], b[2 + 3 * n:2 + 4 * n], \
            b[2 + 4 * n:2 + 5 * n]
        s_r = 0.0   # sum(jrdx bx + w V0)
        s_q = 0.0   # sum Q0
        V0s, P0s = [], []
        for (dq, i11, i12, i21, i22, cjvx, cjvzdz, cjpx, cjpqdq, cq, w, jrdx), x, v, zz, p, q \
                in zip(per1, bx, bv, bz, bp, bq):
            s1 = v + cjvx * x + cjvzdz * zz
            s2 = p + cjpx * x + cjpqdq * q
            V0 = i11 * s1 + i12 * s2
            P0 = i21 * s1 + i22 * s2
            s_r += jrdx * x + w * V0
            s_q += dq * q + cq * P0
            V0s.append(V0)
            P0s.append(P0)
        # sum(jrdx X + jrdv V) = sum(jrdx bx) + sum(w V), X = bx + c V, w = c jrdx + jrdv
        g0 = b[0]
        g1 = b[1] + c * s_r
        g2 = b[2 + 5 * n] + cb * s_q
        (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = ai
        R = a00 * g0 + a01 * g1 + a02 * g2
        RD = a10 * g0 + a11 * g1 + a12 * g2
        PJ = a20 * g0 + a21 * g1 + a22 * g2
        X, V, Z, P, Q = [], [], [], [], []
        for (dz, dq, cq, Vr, Vrd, Vpj, Pr, Prd, Ppj, cjzv, cjzp, cqpj), V0, P0, x, zz, q \
                in zip(per2, V0s, P0s, bx, bz, bq):
            vv = V0 + Vr * R + Vrd * RD + Vpj * PJ
            pp = P0 + Pr * R + Prd * RD + Ppj * PJ
            X.append(x + c * vv)
            V.append(vv)
            Z.append(dz * (zz + cjzv * vv + cjzp * pp))
            P.append(pp)
            Q.append(dq * q + cq * pp + cqpj * PJ)
        return [R, RD] + X + V + Z + P + Q + [PJ]


    # ------------------------------------------------------------------ several z per rope

    def _factor_multi(self, jac, c):
        """`factor` for M > 1 friction states per rope: each z_j row eliminates on its own."""
        rows, cage, jjj = jac
        cc = c * c
        per1, per2 = [], []
        m10 = m11 = m12 = 0.0
        m20 = m21 = m22 = 0.0
        hoist = cage is not None
        if hoist:
            invM, jrdr, jrdrd = cage
        for (jvr, jvrd, jvx, jvv, jvz, jvp, jzv, jzz, jzp, jpx, jpv, jpq, jqp, jqpj, jqq, hk, hc, jpp) in rows:
            dz = [1.0 / (1.0 - c * a) for a in jzz]
            svv = svp = 0.0
            for a, b, d, e in zip(jvz, jzv, jzp, dz):
                svv += a * b * e
                svp += a * d * e
            dq = 1.0 / (1.0 - c * jqq)
            a11 = 1.0 - c * jvv - cc * jvx - cc * svv
            a12 = -c * jvp - cc * svp
            a21 = -c * jpv - cc * jpx
            a22 = 1.0 - c * jpp - cc * jpq * jqp * dq
            det = a11 * a22 - a12 * a21
            i11, i12, i21, i22 = a22 / det, -a12 / det, -a21 / det, a11 / det
            e1r, e1rd, e2pj = c * jvr, c * jvrd, cc * jpq * dq * jqpj
            Vr, Vrd, Vpj = i11 * e1r, i11 * e1rd, i12 * e2pj
            Pr, Prd, Ppj = i21 * e1r, i21 * e1rd, i22 * e2pj
            cq = dq * c * jqp
            Qr, Qrd, Qpj = cq * Pr, cq * Prd, cq * Ppj + dq * c * jqpj
            jrdx = hk * invM if hoist else 0.0
            w = (c * hk + hc) * invM if hoist else 0.0
            m10 += w * Vr
            m11 += w * Vrd
            m12 += w * Vpj
            m20 += Qr
            m21 += Qrd
            m22 += Qpj
            per1.append((dq, i11, i12, i21, i22, c * jvx, tuple(c * a * e for a, e in zip(jvz, dz)), c * jpx,
                         c * jpq * dq, cq, w, jrdx))
            per2.append((dz, dq, cq, Vr, Vrd, Vpj, Pr, Prd, Ppj, tuple(c * a for a in jzv), tuple(c * a for a in jzp),
                         dq * c * jqpj))
        cb = c * self.bVj
        if hoist:
            a = ((1.0, -c, 0.0),
                 (-c * jrdr - c * m10, 1.0 - c * jrdrd - c * m11, -c * m12),
                 (-cb * m20, -cb * m21, 1.0 - cb * m22 - c * jjj))
        else:
            a = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (-cb * m20, -cb * m21, 1.0 - cb * m22 - c * jjj))
        return per1, per2, _inv3(a), c, cb

    def _solve_multi(self, fac, b):
        per1, per2, ai, c, cb = fac
        n, nz = self.n, self.nz
        o = 2 + 2 * n + n * nz
        bx, bv, bp, bq = b[2:2 + n], b[2 + n:2 + 2 * n], b[o:o + n], b[o + n:o + 2 * n]
        bz = [b[2 + 2 * n + i * nz:2 + 2 * n + (i + 1) * nz] for i in range(n)]
        s_r = 0.0
        s_q = 0.0
        V0s, P0s = [], []
        for (dq, i11, i12, i21, i22, cjvx, cjvzdz, cjpx, cjpqdq, cq, w, jrdx), x, v, zz, p, q \
                in zip(per1, bx, bv, bz, bp, bq):
            s1 = v + cjvx * x
            for a, e in zip(cjvzdz, zz):
                s1 += a * e
            s2 = p + cjpx * x + cjpqdq * q
            V0 = i11 * s1 + i12 * s2
            P0 = i21 * s1 + i22 * s2
            s_r += jrdx * x + w * V0
            s_q += dq * q + cq * P0
            V0s.append(V0)
            P0s.append(P0)
        g0 = b[0]
        g1 = b[1] + c * s_r
        g2 = b[o + 2 * n] + cb * s_q
        (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = ai
        R = a00 * g0 + a01 * g1 + a02 * g2
        RD = a10 * g0 + a11 * g1 + a12 * g2
        PJ = a20 * g0 + a21 * g1 + a22 * g2
        X, V, Z, P, Q = [], [], [], [], []
        for (dz, dq, cq, Vr, Vrd, Vpj, Pr, Prd, Ppj, cjzv, cjzp, cqpj), V0, P0, x, zz, q \
                in zip(per2, V0s, P0s, bx, bz, bq):
            vv = V0 + Vr * R + Vrd * RD + Vpj * PJ
            pp = P0 + Pr * R + Prd * RD + Ppj * PJ
            X.append(x + c * vv)
            V.append(vv)
            Z.extend([d * (e + a * vv + f * pp) for d, e, a, f in zip(dz, zz, cjzv, cjzp)])
            P.append(pp)
            Q.append(dq * q + cq * pp + cqpj * PJ)
        return [R, RD] + X + V + Z + P + Q + [PJ]


def _inv3(a):
    """Inverse of a 3x3 matrix (tuple of rows) by the adjugate."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    c00 = a11 * a22 - a12 * a21
    c01 = a12 * a20 - a10 * a22
    c02 = a10 * a21 - a11 * a20
    det = a00 * c00 + a01 * c01 + a02 * c02
    return ((c00 / det, (a02 * a21 - a01 * a22) / det, (a01 * a12 - a02 * a11) / det),
            (c01 / det, (a00 * a22 - a02 * a20) / det, (a02 * a10 - a00 * a12) / det),
            (c02 / det, (a01 * a20 - a00 * a21) / det, (a00 * a11 - a01 * a10) / det))


def settle_rows(solve_states, n: int, nz: int, y: list, zh, c: float) -> None:
    """`Stepper.settle` for any state list y (the dense solver's too): rope i's element rows by
    `solve_states(v_i, zh_i, pm_i, c, z_i)`, in place."""
    zo = 2 + 2 * n
    o = zo + n * nz
    for i in range(n):
        p = y[o + i]
        a = zo + i * nz
        y[a:a + nz] = solve_states(y[2 + n + i], zh[i * nz:(i + 1) * nz], p * 1e-6 if p > 0.0 else 0.0, c,
                                   y[a:a + nz])


NEWTON_MAX = 12         # settled laws: Newton iterations per implicit step at most
CONTACT_NEWTON_MAX = 4  # other laws: Newton iterations of a step across which an end-stop contact changes
NEWTON_V_TOL = 1e-7     # m/s: ... until no piston velocity moves by more than this (+ 1e-6 relative)


def _newton_settled(rhs, factor, solve, settle, k1, c, y0, f0, jac, hist, zrows, vrows):
    """The implicit step y+ = hist + c f(t + h, y+) (BDF2; implicit Euler: hist = y) of a law
    with `solve_states` (Maxwell-slip, elasto-plastic): Newton from y0 (f0, jac there), each
    iterate's friction rows re-solved exactly (`Stepper.settle`), until the piston velocities
    settle.

    One linearised step is not enough for these laws: a piston velocity reversal inside the step
    flips each element (elasto-plastic: the one deflection beyond z_ss) from sliding (no
    stiffness) to sticking (k_j; sigma0), which the linearisation
    about the start does not see, and a plain Newton iteration cycles across v = 0. So an
    iterate never crosses v = 0 in one go: the Newton step is cut where the first piston
    reaches v = 0 (that piston exactly 0), and the next linearisation there (every element
    sticking) sees the new side. Where the iteration does not settle within NEWTON_MAX (the
    Stribeck curve's falling branch can give the step's equations several roots at these step
    sizes), the iterate with the smallest velocity residual is taken. Generic over sequences:
    the dense solver calls it with its own rhs / factor / solve. Returns y+ (a list)."""
    zh = hist[zrows]
    v0 = vrows.start
    nv = vrows.stop - v0
    y = y0
    best, best_y = math.inf, None
    for it in range(NEWTON_MAX):
        if it:
            f0, jac = rhs(k1, y, True)
            res = max(abs(c * f0[i] - (y[i] - hist[i])) for i in range(v0, v0 + nv))
            if res < best:
                best, best_y = res, y
        d = solve(factor(jac, c), [c * f - (a - b) for f, a, b in zip(f0, y, hist)])
        lam, cut = 1.0, -1
        for i in range(v0, v0 + nv):
            a = y[i]
            b = a + d[i]
            if (a > 0.0 and b < 0.0) or (a < 0.0 and b > 0.0):
                r = a / (a - b)
                if r < lam:
                    lam, cut = r, i
        if cut < 0:
            yn = [a + e for a, e in zip(y, d)]
        else:
            yn = [a + lam * e for a, e in zip(y, d)]
            yn[cut] = 0.0
        settle(yn, zh, c)
        done = cut < 0 and all(abs(a - b) <= NEWTON_V_TOL + 1e-6 * abs(a) for a, b in zip(yn[vrows], y[vrows]))
        y = yn
        if done:
            return y
    f0 = rhs(k1, y, False)
    if max(abs(c * f0[i] - (y[i] - hist[i])) for i in range(v0, v0 + nv)) < best:
        return y
    return list(best_y)


def integrate_fast(plant, u, y0, grid_steps, progress=None, jac_every: int = 1, keep: bool = True,
                   chunk: int = 20000, method: str = "bdf2"):
    """Step over the grid indices `grid_steps` (ascending, starting at 0); states there, shape (len, n).

    method "bdf2" (default): variable-step BDF2 linearised about the extrapolated state (one Jacobian,
    one solve per step; the first step linearly implicit Euler); "ros2": the ROS2 of `solver`. With the
    piston mode (~200 Hz) and the LuGre bristles far beyond 1/h, the piston velocity behaves like an
    index-2 variable (x is fixed by the force balance, v = x'): ROS2's stages then leave x, v and z
    inconsistent (x drifted 0.5 mm from the integral of v over the field trip) and the friction wrong;
    BDF2 is stiffly accurate, y+ comes from f(y+) itself (docs/simulator.md).
    jac_every > 1 keeps W's factors for that many steps of equal size (ROS2 is a W-method: second
    order with any W; only stability can suffer). keep=False returns only the last state (long
    benchmark runs). Inputs are turned into Python lists `chunk` steps at a time, so long runs do
    not hold every grid point as Python floats."""
    if method not in METHODS:
        raise ValueError(f"method: must be one of {METHODS}, got {method!r}")
    bdf2 = method == "bdf2"
    y_prev = None
    h_prev = 0.0
    st = Stepper(plant, u.take(np.array(grid_steps[:1])))
    h0 = float(u.t[1] - u.t[0]) if len(u.t) > 1 else 1.0
    y = [float(a) for a in y0]
    nsteps = len(grid_steps) - 1
    Y = np.empty((nsteps + 1 if keep else 1, len(y)))
    Y[0] = y
    every = max(nsteps // 100, 1)
    rhs, factor, solve = st.rhs, st.factor, st.solve
    settle = st.settle if st.solve_states is not None else None
    zrows = slice(2 + 2 * st.n, 2 + 2 * st.n + st.n * st.nz)
    vrows = slice(2 + st.n, 2 + 2 * st.n)
    stops = plant.end_stops is not None
    hmin = min(st.half)                     # no piston beyond this: no contact to check
    x0, x1 = 2, 2 + st.n
    fac = None
    last_h = 0.0
    age = 0
    for j0 in range(0, nsteps, chunk):
        j1 = min(j0 + chunk, nsteps)
        st.set_inputs(u.take(np.asarray(grid_steps[j0:j1 + 1])))
        for j in range(j0, j1):
            h = (grid_steps[j + 1] - grid_steps[j]) * h0
            k0, k1 = j - j0, j - j0 + 1          # rows of this chunk's inputs
            if bdf2:
                if y_prev is None:
                    # first step: linearly implicit Euler, W = I - h J(t + h, y)
                    f0, jac = rhs(k1, y, True)
                    if settle is None:
                        d = solve(factor(jac, h), f0)
                        y_prev, y = y, [a + h * b for a, b in zip(y, d)]
                    else:   # settled law: implicit Euler solved by the same Newton as below
                        y_prev, y = y, _newton_settled(rhs, factor, solve, settle, k1, h, y, f0, jac, y, zrows,
                                                       vrows)
                else:
                    # variable-step BDF2, y+ - a y + b y- = be h f(t + h, y+), by one Newton step
                    # from the linear extrapolation yp (so the linearisation error is O(h^4))
                    om = h / h_prev
                    den = 1.0 + 2.0 * om
                    be, a2, b2 = (1.0 + om) / den, (1.0 + om) ** 2 / den, om * om / den
                    yp = [a + om * (a - b) for a, b in zip(y, y_prev)]
                    fp, jac = rhs(k1, yp, True)
                    c = be * h
                    if settle is None:
                        d = solve(factor(jac, c), [c * f - (p - a2 * a + b2 * b)
                                                   for f, p, a, b in zip(fp, yp, y, y_prev)])
                        yn = [p + e for p, e in zip(yp, d)]
                        if stops and (st.touched or max(map(abs, yn[x0:x1])) > hmin) \
                                and st.contacts(yn) != st.contacts(yp):
                            # the step was linearised on the other side of a contact switch: Newton
                            # iterations from its result until the contacts hold (docs/simulator.md)
                            hist = [a2 * a - b2 * b for a, b in zip(y, y_prev)]
                            for _ in range(CONTACT_NEWTON_MAX):
                                was = st.contacts(yn)
                                f1, jac1 = rhs(k1, yn, True)
                                d = solve(factor(jac1, c), [c * f - (a - b) for f, a, b in zip(f1, yn, hist)])
                                yn = [a + e for a, e in zip(yn, d)]
                                if st.contacts(yn) == was:
                                    break
                        y_prev, y = y, yn
                    else:
                        hist = [a2 * a - b2 * b for a, b in zip(y, y_prev)]
                        y_prev, y = y, _newton_settled(rhs, factor, solve, settle, k1, c, yp, fp, jac, hist,
                                                       zrows, vrows)
                h_prev = h
                if keep:
                    Y[j + 1] = y
                if progress is not None and j % every == 0:
                    progress(j, nsteps)
                continue
            if fac is None or h != last_h or age >= jac_every:
                f0, jac = rhs(k0, y, True)
                fac = factor(jac, GAMMA * h)
                last_h, age = h, 0
            else:
                f0 = rhs(k0, y)
            age += 1
            s1 = solve(fac, f0)
            f1 = rhs(k1, [a + h * b for a, b in zip(y, s1)])
            s2 = solve(fac, [a - 2.0 * b for a, b in zip(f1, s1)])
            y = [a + h * (1.5 * b + 0.5 * c) for a, b, c in zip(y, s1, s2)]
            if keep:
                Y[j + 1] = y
            if progress is not None and j % every == 0:
                progress(j, nsteps)
    if not keep:
        Y[0] = y
    if not np.all(np.isfinite(Y[-1])):
        raise FloatingPointError("the plant state became non-finite: step too large for this scenario?")
    return Y
