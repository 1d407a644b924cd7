"""Sensor words -> engineering integers, with the NAMUR NE43 loop check.

Per rope: pressure counts -> sensor pressure (kPa) and raw tension p_tap*A (N),
displacement counts -> piston position (1/256 um). A pressure loop below
3.6 mA or above 21 mA (fault_lo/hi_counts, computed by the host builder) is a
failed signal: its bit is set in `fault_mask`, the last good values are kept
for the state updates and the rope gets no tension. Allocation-free.
"""
import array

from micropython import const

PRESSURE_FAULT_BIT0 = const(0)      # fault_mask bit i: pressure loop of rope i failed
DISPLACEMENT_FAULT_BIT0 = const(4)  # fault_mask bit 4+i: displacement of rope i failed


class Channels:
    def __init__(self, cfg):
        n = self.n = cfg.ropes
        self.pcal = cfg.pressure       # 9 ints per rope, config.py order
        self.dcal = cfg.displacement   # 6 ints per rope
        self.p_kpa = array.array("i", [0] * n)       # sensor (tap) pressure, kPa
        self.raw_tension_n = array.array("i", [0] * n)  # p_tap * A, N
        self.x_q8um = array.array("i", [0] * n)      # piston position, um/256
        self.fault_mask = 0
        self.seen = 0  # bit i / 4+i: a good pressure / displacement value was read once

    def read(self, rec):
        """Convert one record's pressure and displacement words; return fault_mask."""
        n = self.n
        pc = self.pcal
        dc = self.dcal
        mask = 0
        for i in range(n):
            c = rec[i]
            b = 9 * i
            if c < pc[b + 1] or c > pc[b + 2]:
                mask |= 1 << i
            else:
                d = c - pc[b]
                self.p_kpa[i] = pc[b + 3] + ((d * pc[b + 4]) >> pc[b + 5])
                self.raw_tension_n[i] = pc[b + 6] + ((d * pc[b + 7]) >> pc[b + 8])
                self.seen |= 1 << i
            c = rec[n + i]
            b = 6 * i
            if c < dc[b + 1] or c > dc[b + 2]:
                mask |= 16 << i
            else:
                self.x_q8um[i] = dc[b + 3] + ((c - dc[b]) * dc[b + 4] >> dc[b + 5])
                self.seen |= 16 << i
        self.fault_mask = mask
        return mask
