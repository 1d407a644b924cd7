"""Piston velocity: the derivative of the low-pass filtered piston position.

x_f += alpha (x - x_f) (first order, alpha = 1 - exp(-2 pi fc / fs)); the
per-sample increment dx = x_f(k) - x_f(k-1) is clamped to +-v_max / fs and
v = dx * fs. Filtering the position rather than the raw derivative gives the
same low-pass velocity, and at rest x_f settles so dx is exactly 0: the LuGre
state, which integrates dx, cannot creep. Units: x_f and dx in um/256, v in
um/s. Allocation-free.
"""
import array


class Velocity:
    def __init__(self, cfg):
        n = self.n = cfg.ropes
        self.alpha_q14 = cfg.alpha_q14
        self.dx_max = cfg.dx_max_q8um
        self.fs = cfg.sample_hz
        self.xf = array.array("i", [0] * n)        # filtered position, um/256
        self.dx_q8um = array.array("i", [0] * n)   # this sample's increment, um/256
        self.v_um_s = array.array("i", [0] * n)
        self.started = 0  # bit i: xf[i] initialised from a good position

    def update(self, x_q8um, good):
        """Advance every rope whose bit in `good` is set; others hold (dx = 0)."""
        a = self.alpha_q14
        m = self.dx_max
        fs = self.fs
        xf = self.xf
        for i in range(self.n):
            if not (good >> i) & 1:
                self.dx_q8um[i] = 0  # position unknown: the piston is taken as still
                self.v_um_s[i] = 0
                continue
            if not (self.started >> i) & 1:
                xf[i] = x_q8um[i]
                self.started |= 1 << i
            e = x_q8um[i] - xf[i]  # |e| < 2**26: positions are within +-2**25
            # e * a / 2**14 rounded, split so no product exceeds 2**28
            step = (e >> 14) * a + (((e & 16383) * a + 8192) >> 14)
            dx = step
            if dx > m:
                dx = m
            elif dx < -m:
                dx = -m
            xf[i] += dx
            self.dx_q8um[i] = dx
            self.v_um_s[i] = (dx * fs + 128) >> 8
