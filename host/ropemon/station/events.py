"""`AlarmEvent`: what the station tells the log and every face, one event at a time.

The alarm engine's events (raise, clear, ack, shelve, unshelve, out_of_service, in_service)
carry the alarm's `value` and `threshold`. The station's own events carry their numbers in
named fields: `accept` (an operator trusts a node whose boot counter went back) the boots,
`rebase` (the frame taken as the node's new baseline) the sequence numbers, `error` (a
listener or receiver failing) a count. The log keeps those numbers in its `value` and
`threshold` columns (`row`, `from_row`), and the faces show them there (`columns`, `to_dict`).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

#: per action of the station's own events: its named fields kept in the log's (value, threshold)
STATION_NUMBERS: dict[str, tuple[str, str | None]] = {
    "accept": ("newest_boot", "frame_boot"),
    "rebase": ("seq", "prev_seq"),
    "error": ("count", None),
}
#: the columns of the log's events table an event fills (`row`)
ROW_COLUMNS = ("time_s", "action", "alarm", "kind", "node", "rope", "value", "threshold", "message", "worst",
               "operator")


@dataclass(frozen=True, kw_only=True)
class AlarmEvent:
    time_s: float
    action: str          # raise, clear, ack, shelve, unshelve, out_of_service, in_service; station: accept, ...
    alarm: str           # id, e.g. "deviation:n1:r2"
    kind: str
    message: str
    node: int | None = None
    rope: int | None = None         # from 0 (the screen, the CSV and JSON number ropes from 1)
    value: float | None = None      # the alarm's value (engine events)
    threshold: float | None = None  # the alarm's limit (engine events)
    worst: float | None = None      # the worst value since the alarm was raised
    operator: str | None = None     # who acted (ack, shelve, ...), None for the engine's own
    annunciated: bool = True        # False: raised while shelved, out of service or suppressed
    seq: int | None = None          # rebase: the frame's seq taken as the node's new baseline
    prev_seq: int | None = None     # rebase: the baseline's seq before
    newest_boot: int | None = None  # accept: the newest boot the station had seen from the node
    frame_boot: int | None = None   # accept: the boot of the node's refused frames
    count: int | None = None        # error: how many times the part has failed so far

    def columns(self) -> tuple[float | None, float | None]:
        """(value, threshold) as the log stores them and the faces show them: the alarm's, or a
        station event's named numbers (`STATION_NUMBERS`)."""
        value, threshold = self.value, self.threshold
        names = STATION_NUMBERS.get(self.action)
        if names is not None:
            if value is None:
                value = getattr(self, names[0])
            if threshold is None and names[1] is not None:
                threshold = getattr(self, names[1])
        return value, threshold

    def row(self) -> dict[str, Any]:
        """The log's columns (`ROW_COLUMNS`) of this event."""
        value, threshold = self.columns()
        out = {c: getattr(self, c) for c in ROW_COLUMNS}
        out["value"], out["threshold"] = value, threshold
        return out

    @classmethod
    def from_row(cls, row: dict[str, Any]) -> "AlarmEvent":
        """An event read back from a row of the log (`Store.events`): a station event's numbers
        into their named fields. Rows of every log, old or new, have the same form."""
        kw = {f.name: row[f.name] for f in dataclasses.fields(cls) if f.name in row and f.name != "annunciated"}
        names = STATION_NUMBERS.get(row.get("action") or "")
        if names is not None:
            for name, col in zip(names, ("value", "threshold")):
                if name is not None:
                    v = kw.pop(col, None)
                    kw[name] = None if v is None else int(v)
        return cls(**kw)

    def to_dict(self) -> dict:
        """Every field; `value` and `threshold` as `columns` gives them (the JSON faces' keys)."""
        out = dict(self.__dict__)
        out["value"], out["threshold"] = self.columns()
        return out
