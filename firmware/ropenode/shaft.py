"""Cage depth and hoist speed from the up/down pulse counter and the shaft Hall marks.

Depth (mm, positive downwards) integrates the counter's wrapped difference
(modulo 2**16) times mm per pulse; the fraction is kept in Q16 so nothing is
lost over a trip. When the Hall pair first reads a mark (bits 0|1 go from 0 to
non-zero) the depth snaps to the nearest configured mark within snap_mm. A
counter jump beyond max_pulses_per_sample is ignored and flagged (speed
fault), as is a mark seen with no pulse over the last two frame windows.
Allocation-free.
"""
from micropython import const

_NEVER = const(-1)


class Shaft:
    def __init__(self, cfg):
        self.mmpp = cfg.mm_per_pulse_q16
        self.maxp = cfg.max_pulses_per_sample
        self.marks = cfg.marks_mm
        self.snap = cfg.snap_mm
        self.depth_mm = cfg.start_depth_mm
        self.frac_q16 = 0
        self.prev_count = _NEVER
        self.prev_hall = 0
        self.win_q16 = 0        # travel in this window, mm/65536
        self.win_pulses = 0     # |pulses| this window
        self.last_win_pulses = 0
        self.fault = False      # latched until the window closes
        self.marks_seen = 0

    def update(self, count, hall):
        prev = self.prev_count
        self.prev_count = count
        if prev >= 0:
            d = (count - prev) & 0xFFFF
            if d >= 0x8000:
                d -= 0x10000
            if d > self.maxp or d < -self.maxp:
                self.fault = True
            elif d:
                t = d * self.mmpp
                self.win_q16 += t
                self.win_pulses += d if d > 0 else -d
                f = self.frac_q16 + t
                self.depth_mm += f >> 16
                self.frac_q16 = f & 0xFFFF
        hall &= 3
        if hall and not self.prev_hall:
            self.marks_seen += 1
            if self.win_pulses == 0 and self.last_win_pulses == 0:
                self.fault = True
            self._snap()
        self.prev_hall = hall

    def _snap(self):
        m = self.marks
        best = -1
        bd = self.snap + 1
        dep = self.depth_mm
        for j in range(len(m)):
            d = m[j] - dep
            if d < 0:
                d = -d
            if d < bd:
                bd = d
                best = j
        if best >= 0:
            self.depth_mm = m[best]
            self.frac_q16 = 0

    def close_window(self, frame_hz):
        """Speed over the closed window (mm/s, clamped to int16); resets the window."""
        s = ((self.win_q16 >> 10) * frame_hz) >> 6  # win_q16 < 2**29, frame_hz <= 1000
        self.win_q16 = 0
        self.last_win_pulses = self.win_pulses
        self.win_pulses = 0
        if s > 32767:
            s = 32767
        elif s < -32767:
            s = -32767
        return s
