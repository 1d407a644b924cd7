"""The evidence for the sensor_stuck alarm (`ropemon.station.alarms`): a rope's pressure frozen
while the others move (`StuckTracker`)."""
from __future__ import annotations

from ropemon.station.equalizer import _median_without


class StuckTracker:
    """One node's evidence for sensor_stuck: O(ropes) state, constant work per frame.

    A 4-20 mA transmitter frozen inside the band (electronics hung, diaphragm blocked, a
    valve closed at the tap) gives a plausible constant: NAMUR NE43 cannot see it. The
    connected cylinders share the load, so a live rope's tap pressure moves with the
    others; and a live transmitter's noise moves its window mean. Per rope this keeps an
    anchor (the raw_kpa it has stayed within +-deadband of, and since when) and the range
    of the mean of the other present ropes' raw_kpa since that anchor. Stuck = still for
    stuck_s while the others moved by more than stuck_others_kpa: never at rest (nobody
    moved), and a live rope moving with the others resets its own anchor.

    The deadband (5 kPa) is wider than the 1 kPa resolution because a frozen loop current
    still passes the ADC noise: 1 count = 1.3 kPa on a 0-25 MPa, 16-bit channel, and with 3
    counts of noise (the `sensor-noise` evaluation) the window mean of a frozen reading spans
    +-3 kPa, which a 1 or 2 kPa deadband takes for movement (missed or flickering alarm).
    It stays far below the others' 50 kPa: on the evaluation's streams through the firmware
    (all variants, duty-cycle-50's 50 winds included) no live rope held within +-5 kPa for
    5 s while the others moved more than 10 kPa.
    The others' mean, not each other rope, keeps the state O(ropes); when the set of present
    ropes changes that mean jumps, so every anchor restarts.
    """

    __slots__ = ("present", "anchor_kpa", "anchor_s", "lo_kpa", "hi_kpa", "median")

    def __init__(self, median: bool = False) -> None:
        # median: the others' median instead of their mean (the station with the equalizer's alarms:
        # a cylinder cut off from the manifold parts its pressure from the rest, which then must not
        # look stuck against it); the same for up to three ropes
        self.median = median
        self.present: tuple[bool, ...] = ()
        self.anchor_kpa: list[int] = []
        self.anchor_s: list[float] = []
        self.lo_kpa: list[float] = []
        self.hi_kpa: list[float] = []

    def update(self, raw_kpa: list[int], present: tuple[bool, ...], now_s: float, deadband_kpa: int) -> None:
        """Take one frame's raw_kpa per rope (present: not RAW_KPA_ABSENT)."""
        total = 0
        for p, kpa in zip(present, raw_kpa):
            if p:
                total += kpa
        count = sum(present)
        if self.median and count > 3:
            srt = sorted(k for p, k in zip(present, raw_kpa) if p)

            def others_of(kpa: int) -> float:
                return _median_without(srt, kpa)
        else:
            def others_of(kpa: int) -> float:
                return (total - kpa) / (count - 1)
        if present != self.present:
            n = len(raw_kpa)
            self.present = present
            self.anchor_kpa = list(raw_kpa)
            self.anchor_s = [now_s] * n
            self.lo_kpa = [0.0] * n
            self.hi_kpa = [0.0] * n
            for i in range(n):
                if present[i] and count > 1:
                    self.lo_kpa[i] = self.hi_kpa[i] = others_of(raw_kpa[i])
            return
        if count < 2:
            return
        for i, kpa in enumerate(raw_kpa):
            if not present[i]:
                continue
            others = others_of(kpa)
            if abs(kpa - self.anchor_kpa[i]) > deadband_kpa:
                self.anchor_kpa[i], self.anchor_s[i] = kpa, now_s
                self.lo_kpa[i] = self.hi_kpa[i] = others
            elif others < self.lo_kpa[i]:
                self.lo_kpa[i] = others
            elif others > self.hi_kpa[i]:
                self.hi_kpa[i] = others
