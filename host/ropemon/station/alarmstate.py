"""One alarm's state in the alarm engine (`ropemon.station.alarms`): its debounce (`Timing`,
`Debounce`) and its lifecycle record (`_Alarm`: latched, acknowledged, shelved, out of service,
suppressed; its worst value since raised).

The debounce: a condition raises only after it has held for `raise_after_s` over at least
`min_frames` consecutive evaluations, and clears only after the clear condition has held for
`clear_after_s` likewise. `ropemon.lab.metrics.debounced` runs the same over an evaluation's frames.
"""
from __future__ import annotations

from dataclasses import dataclass

#: Kinds whose worst value is the lowest (the others: the largest in magnitude).
WORST_LOW = frozenset({"slack", "battery_low", "not_equalizing", "rope_adjust"})
# A condition "held for 0.5 s" over frames 0.1 s apart holds at the sixth frame, whatever the
# float rounding of the two times (38 * 0.1 and 43 * 0.1 are 0.49999999999999 apart).
HOLD_TOLERANCE_S = 1e-6


@dataclass(frozen=True)
class Timing:
    """Debounce of one alarm kind."""

    raise_after_s: float = 0.5
    clear_after_s: float = 2.0
    min_frames: int = 2


@dataclass
class Debounce:
    """The debounce of one alarm condition (module doc): `step` takes one evaluation and says
    when the debounced condition raises or clears. The engine holds one per alarm;
    `ropemon.lab.metrics.debounced` runs the same over an evaluation's frames."""

    timing: Timing
    present: bool = False        # debounced condition
    since_s: float | None = None  # start of the pending change
    since_n: int = 0

    def step(self, now_s: float, raise_cond: bool, clear_cond: bool) -> str | None:
        """'raise' or 'clear' when the debounced condition changes at this evaluation, else None."""
        want = clear_cond if self.present else raise_cond
        if not want:
            self.since_s, self.since_n = None, 0
            return None
        if self.since_s is None:
            self.since_s, self.since_n = now_s, 0
        self.since_n += 1
        t = self.timing
        hold = t.clear_after_s if self.present else t.raise_after_s
        if now_s - self.since_s < hold - HOLD_TOLERANCE_S or self.since_n < t.min_frames:
            return None
        self.since_s, self.since_n = None, 0
        self.present = not self.present
        return "raise" if self.present else "clear"



@dataclass
class _Alarm:
    id: str
    kind: str
    node: int | None
    rope: int | None
    debounce: Debounce
    latched: bool = False        # raised and not acknowledged
    value: float | None = None
    threshold: float | None = None
    message: str = ""
    raised_s: float | None = None
    band: float | None = None    # deviation_possible: the deviation's band (fraction)
    worst: float | None = None   # worst value since raised
    cleared_s: float | None = None
    acked_s: float | None = None
    acked_by: str | None = None
    shelved_until: float | None = None
    shelved: str | None = None   # "reason, by whom" while shelved
    out_of_service: str | None = None  # "reason, by whom" while out of service
    suppressed: bool = False     # by design (its rope's sensor failed)

    @property
    def present(self) -> bool:
        return self.debounce.present

    @property
    def active(self) -> bool:
        return self.present or self.latched

    @property
    def hidden(self) -> bool:
        """Not annunciated: shelved, out of service or suppressed by design."""
        return self.shelved is not None or self.out_of_service is not None or self.suppressed

    def state(self) -> str:
        if self.out_of_service is not None:
            return "out_of_service"
        if self.shelved is not None:
            return "shelved"
        if self.suppressed:
            return "suppressed"
        if self.present:
            return "unacknowledged" if self.latched else "acknowledged"
        return "rtn_unacknowledged" if self.latched else "normal"


def _worse(kind: str, worst: float | None, value: float | None) -> float | None:
    if value is None or worst is None:
        return worst if value is None else value
    if kind in WORST_LOW:
        return min(worst, value)
    return value if abs(value) > abs(worst) else worst
