"""LuGre seal friction per rope, integer implicit-Euler update (stable at any step).

With zf = sigma0 z (N) and the step's elastic increment w = sigma0 dx, the
implicit Euler step of dz/dt = v - sigma0 |v| z / g(v) is

    zf+ = g (zf + w) / (g + |w|)  =  zss + (zf - zss) g / (g + |w|),  zss = sgn(w) g

so |zf| never exceeds max g, whatever the step (explicit Euler diverges once
h sigma0 |v| / g > 2). The friction force on the rope side is

    F = zf+ + c1 (zf+ - zf) + sigma2(p) v,   c1 = sigma1 / (sigma0 h)

g(v) = Fc + (Fs - Fc) E(|v| / vs), E(u) = exp(-u^2) by table (Q14, u step 1/32).
Fs, Fc, vs, sigma2 are linear in the sensor pressure (clamped to 0..p_kpa_max).
Units: zf, g, F in N/16 (Q4); w is accumulated with error feedback so the sum
of increments is exact. Every product stays below 2**30 (bounds in
docs/model.md, checked by config.parse and ropemon.nodeconfig). Allocation-free.
"""
import array


def muldiv_round(a, b, c):
    """round(a * b / c) for 0 <= a < 2**20, 0 <= b < 2**19, b < c < 2**20, without
    any intermediate reaching 2**30 (b is split into 9 high and 10 low bits)."""
    t = a * (b >> 10)
    q1 = t // c
    t = (t - q1 * c) << 10
    q2 = t // c
    r2 = t - q2 * c
    t = a * (b & 1023)
    q3 = t // c
    r3 = t - q3 * c
    return (q1 << 10) + q2 + q3 + (r2 + r3 + (c >> 1)) // c


class LuGre:
    def __init__(self, cfg):
        n = self.n = cfg.ropes
        self.cfg = cfg
        self.pmax = cfg.p_kpa_max
        self.zf = array.array("i", [0] * n)     # sigma0 z, N/16
        self.wrem = array.array("i", [0] * n)   # error-feedback remainder of w
        self.g = array.array("i", [0] * n)      # g(v) of the last step, N/16
        self.friction_q4 = array.array("i", [0] * n)  # F, N/16
        self.friction_n = array.array("i", [0] * n)   # F, N (rounded)

    def reset(self, i):
        self.zf[i] = 0
        self.wrem[i] = 0

    def update(self, p_kpa, dx_q8um, v_um_s, active):
        """One step for every rope whose bit in `active` is set."""
        c = self.cfg
        fs0, fsm, fss = c.fs
        fc0, fcm, fcs = c.fc
        vs0, vsm, vss = c.vs
        s20, s2m, s2s = c.s2
        s2s9 = c.sigma2_shift - 9
        s2half = 1 << s2s9 >> 1
        s0m = c.sigma0_mul
        s0s = c.sigma0_shift
        c1m = c.c1_mul
        c1s10 = c.c1_shift - 10
        c1half = 1 << c1s10 >> 1
        tab = c.gexp_q14
        pmax = self.pmax
        zfa = self.zf
        wrem = self.wrem
        for i in range(self.n):
            if not (active >> i) & 1:
                continue
            p = p_kpa[i]
            if p < 0:
                p = 0
            elif p > pmax:
                p = pmax
            fs = fs0 + ((p * fsm) >> fss)
            fc = fc0 + ((p * fcm) >> fcs)
            vs = vs0 + ((p * vsm) >> vss)
            s2 = s20 + ((p * s2m) >> s2s)
            v = v_um_s[i]
            av = v if v >= 0 else -v
            u = (av << 9) // vs  # |v| / vs in Q9; av < 2**20
            if u >= 2048:
                e_q14 = 0
            else:
                k = u >> 4
                e_q14 = tab[k] + (((tab[k + 1] - tab[k]) * (u & 15) + 8) >> 4)
            g = (fc << 4) + (((fs - fc) * e_q14 + 512) >> 10)
            self.g[i] = g
            wf = dx_q8um[i] * s0m + wrem[i]
            w = wf >> s0s
            wrem[i] = wf - (w << s0s)
            z = zfa[i]
            zn = z
            if w:
                if w > 0:
                    aw = w
                    e = z - g
                else:
                    aw = -w
                    e = z + g
                dd = g + aw
                if e >= 0:
                    zn = z - muldiv_round(e, aw, dd)
                else:
                    zn = z + muldiv_round(-e, aw, dd)
                zfa[i] = zn
            d = zn - z  # |d| < 2**20; c1m < 2**19: split d so no product passes 2**29
            f = zn + (((d >> 10) * c1m + (((d & 1023) * c1m) >> 10) + c1half) >> c1s10)
            # sigma2 v: |v| < 2**20 and s2 < 2**18, so v is split at 9 bits
            f += ((v >> 9) * s2 + (((v & 511) * s2) >> 9) + s2half) >> s2s9
            self.friction_q4[i] = f
            self.friction_n[i] = (f + 8) >> 4
