"""Per-frame window statistics of each rope: tension mean, min, max (N) and raw pressure mean.

Only samples whose rope was healthy count; a rope with no healthy sample in
the window has count 0 and goes out as absent. Peaks survive because min and
max are taken over every sample, not over the mean. Allocation-free.
"""
import array

_BIG = 1 << 29


class Window:
    def __init__(self, ropes):
        n = self.n = ropes
        self.sum_n = array.array("i", [0] * n)
        self.min_n = array.array("i", [_BIG] * n)
        self.max_n = array.array("i", [-_BIG] * n)
        self.sum_kpa = array.array("i", [0] * n)
        self.count = array.array("i", [0] * n)
        self.samples = 0
        self.faults = 0      # OR of the fault masks seen in the window
        self.batt_sum = 0

    def add(self, tension_n, p_kpa, good):
        sum_n = self.sum_n
        lo = self.min_n
        hi = self.max_n
        for i in range(self.n):
            if (good >> i) & 1:
                t = tension_n[i]
                sum_n[i] += t
                self.sum_kpa[i] += p_kpa[i]
                self.count[i] += 1
                if t < lo[i]:
                    lo[i] = t
                if t > hi[i]:
                    hi[i] = t

    def reset(self):
        for i in range(self.n):
            self.sum_n[i] = 0
            self.sum_kpa[i] = 0
            self.count[i] = 0
            self.min_n[i] = _BIG
            self.max_n[i] = -_BIG
        self.samples = 0
        self.faults = 0
        self.batt_sum = 0
