"""Pressure loss between cylinder cavity and sensor tap, as a force dp(Q) * A (N).

Tables from the config: per rope, piston-velocity breakpoints (um/s, from 0;
v = Q / A) and, per oil temperature row (centi-degC), the loss force in N.
Linear interpolation in velocity, held flat beyond the last point, odd-symmetric
for negative velocity; then linear in temperature between the two bracketing
rows (clamped at the ends). Allocation-free.
"""
import array


class Loss:
    def __init__(self, cfg):
        n = self.n = cfg.ropes
        self.nv = cfg.loss_nv
        self.nt = cfg.loss_nt
        self.vbp = cfg.loss_v
        self.force = cfg.loss_force_n
        self.temps = cfg.loss_temps_cc
        self.loss_n = array.array("i", [0] * n)
        self.t_row = 0      # lower temperature row
        self.t_w_q10 = 0    # weight of the upper row, Q10
        self.temp_cc = -1 << 29
        self.set_temp(cfg.oil_temp_assumed_cc)

    def set_temp(self, temp_cc):
        """Select the temperature rows for temp_cc (cheap when unchanged)."""
        if temp_cc == self.temp_cc:
            return
        self.temp_cc = temp_cc
        t = self.temps
        nt = self.nt
        if nt == 1 or temp_cc <= t[0]:
            self.t_row = 0
            self.t_w_q10 = 0
            return
        if temp_cc >= t[nt - 1]:
            self.t_row = nt - 2
            self.t_w_q10 = 1024
            return
        j = 0
        while temp_cc >= t[j + 1]:
            j += 1
        self.t_row = j
        self.t_w_q10 = ((temp_cc - t[j]) << 10) // (t[j + 1] - t[j])

    def update(self, v_um_s):
        nv = self.nv
        nt = self.nt
        vbp = self.vbp
        fo = self.force
        row = self.t_row
        w = self.t_w_q10
        for i in range(self.n):
            v = v_um_s[i]
            av = v if v >= 0 else -v
            b = i * nv
            if av >= vbp[b + nv - 1]:
                j = nv - 2
                fr = 1024
            else:
                j = 0
                while av >= vbp[b + j + 1]:
                    j += 1
                # av < 2**19, so av << 10 < 2**29
                fr = ((av - vbp[b + j]) << 10) // (vbp[b + j + 1] - vbp[b + j])
            r0 = (i * nt + row) * nv + j
            f0 = fo[r0] + (((fo[r0 + 1] - fo[r0]) * fr + 512) >> 10)
            if w:
                r1 = r0 + nv
                f1 = fo[r1] + (((fo[r1 + 1] - fo[r1]) * fr + 512) >> 10)
                f0 += ((f1 - f0) * w + 512) >> 10
            self.loss_n[i] = f0 if v >= 0 else -f0
