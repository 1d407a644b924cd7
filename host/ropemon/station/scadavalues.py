"""What the SCADA faces (Modbus TCP, MQTT Sparkplug B, OPC UA) publish of one hoist, in one place.

`HoistValues` is a station listener (one per hoist) that keeps, on the station's thread,
each node's newest frame and what follows from it (per rope tension, deviation from the
mean of the node's ropes, piston position and stroke-limit state), the alarm bits (one bit
per alarm kind: `ALARM_KINDS`, and `EQUALIZER_KINDS` in words of their own), whether the
station vouches for the hoist's ropes now (`vouched`: none of `VOUCH_KINDS` present and
every configured node heard), and each node's standing status (`standing`: the imbalance
the seals' static friction can hide at the current mean rope tension, the alarm engine's
`hoist_status` as `AlarmState.hoist` carries it). A face subclasses it and overrides
`changed(what)` to hand the values to its own thread; no heavy import here.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

from ropemon.station.link import Received
from ropemon.station.pipeline import AlarmState, Listener, StationStatus
from ropemon.station.protocol import Frame, L

#: One bit per alarm kind (bit k = ALARM_KINDS[k]); a kind not listed sets the last bit.
ALARM_KINDS = ("deviation", "deviation_possible", "overload", "slack", "sensor_fault", "sensor_stuck",
               "config_fault", "silent", "no_data", "battery_low", "pressure_noise", "node_imbalance",
               "link_integrity", "receiver_down", "station_fault", "alarm_flood", "other")
#: The equalizer's alarm kinds, one bit each in words of their own (bit k = EQUALIZER_KINDS[k]);
#: in the `ALARM_KINDS` words they set the "other" bit, as any kind not listed there.
EQUALIZER_KINDS = ("stroke_limit", "not_equalizing", "oil_loss", "rope_adjust")
#: While any of these is present the station cannot vouch for the hoist's ropes (shelved or not).
VOUCH_KINDS = frozenset({"silent", "no_data", "receiver_down", "station_fault", "link_integrity", "config_fault"})


def kind_bit(kind: str) -> int:
    try:
        return 1 << ALARM_KINDS.index(kind)
    except ValueError:
        return 1 << (len(ALARM_KINDS) - 1)


def equalizer_bit(kind: str) -> int:
    """The kind's bit in the `EQUALIZER_KINDS` words (0 for any other kind)."""
    return 1 << EQUALIZER_KINDS.index(kind) if kind in EQUALIZER_KINDS else 0


@dataclass(frozen=True)
class RopeValue:
    tension_dan: int | None       # 1 daN = 0.01 kN; None: the rope's sensor gave no healthy sample
    deviation: float | None       # fraction of the mean of the node's present ropes; None: not computable
    pos_01mm: int | None = None   # piston position, 0.1 mm from mid-stroke (x > 0 pulled out by the rope);
                                  # None: no healthy displacement sample, or a version 2 frame (no position)
    stroke: int = 0               # STROKE_LOW | STROKE_HIGH: within the stroke margin of that end in the window

    @property
    def position_mm(self) -> float | None:
        return None if self.pos_01mm is None else self.pos_01mm / 10


STROKE_LOW, STROKE_HIGH = 1, 2    # RopeValue.stroke: near the retracted (low x) end, the extended (high x) end


@dataclass(frozen=True)
class Standing:
    """A node's standing status (not an alarm): the imbalance the seals' static friction can hide
    with the ropes equal, at the current mean rope tension, and one line an operator reads."""

    hidden_frac: float | None     # fraction of the mean rope tension; None: not known now
    text: str | None


@dataclass(frozen=True)
class NodeValues:
    """One node's newest frame, as the faces publish it."""

    node: int
    seq: int
    wall_s: float                 # when the station received it (time.time())
    station_s: float              # the station's clock then (frame age against StationStatus.time_s)
    status: int
    fault_mask: int
    ropes: tuple[RopeValue, ...]
    sum_dan: int | None
    depth_mm: int
    speed_mm_s: int
    battery_mv: int
    oil_temp_c: float | None
    version: int = 2              # the frame's layout version: 2 carries no position
    stroke_mask: int = 0          # the frame's stroke_mask (docs/protocol.md)


POS_ABSENT = getattr(L, "POS_ABSENT", -32768)


def node_values(frame: Frame, wall_s: float, station_s: float) -> NodeValues:
    present = [r.mean_dan for r in frame.ropes if r.mean_dan != L.TENSION_ABSENT]
    mean = sum(present) / len(present) if present else 0.0
    mask = getattr(frame, "stroke_mask", 0) or 0
    ropes = []
    for i, r in enumerate(frame.ropes):
        pos = getattr(r, "pos_01mm", POS_ABSENT)
        pos = None if pos == POS_ABSENT else pos
        stroke = (STROKE_LOW if mask >> i & 1 else 0) | (STROKE_HIGH if mask >> (4 + i) & 1 else 0)
        if r.mean_dan == L.TENSION_ABSENT:
            ropes.append(RopeValue(None, None, pos, stroke))
        else:
            ropes.append(RopeValue(r.mean_dan, (r.mean_dan - mean) / mean if len(present) >= 2 and mean > 0 else None,
                                   pos, stroke))
    return NodeValues(frame.node, frame.seq, wall_s, station_s, frame.status, frame.fault_mask, tuple(ropes),
                      frame.total_dan, frame.depth_mm, frame.speed_mm_s, frame.battery_mv, frame.oil_temp_c,
                      frame.version, mask)


def standing_of(status: Any) -> Standing:
    """A `HoistStatus` (ropemon.station.alarms; None without a band) as the faces publish it."""
    if status is None:
        return Standing(None, None)
    frac = getattr(status, "hidden_frac", None)
    text = getattr(status, "text", None)
    return Standing(None if frac is None or frac != frac else float(frac), None if text is None else str(text))


class HoistValues(Listener):
    """One hoist's values for a SCADA face (module docstring). Runs on the station's thread."""

    name = "scada values"

    def __init__(self, hoist: str, nodes: Iterable[int]) -> None:
        self.hoist = hoist
        self.nodes = tuple(sorted(nodes))
        self.latest: dict[int, NodeValues] = {}
        self.present_bits = 0
        self.unacked_bits = 0
        self.present_eq = 0           # the EQUALIZER_KINDS words
        self.unacked_eq = 0
        self.standing: dict[int, Standing] = {n: Standing(None, None) for n in self.nodes}
        self.vouched = False
        self.heartbeat = 0            # station ticks while vouched (wraps at 65536)
        self.station_s = 0.0          # the station clock at the last tick
        self._tick = False

    # -- the station's messages ----------------------------------------------------------

    def on_frame(self, item: Received, now_s: float) -> None:
        import time
        v = node_values(item.frame, time.time(), now_s)
        self.latest[v.node] = v
        self.changed("frame", v)

    def on_status(self, status: StationStatus) -> None:
        self.station_s = status.time_s
        self._tick = True             # the alarm state of this tick follows (AlarmListener)

    def on_alarms(self, state: AlarmState) -> None:
        present = unacked = present_eq = unacked_eq = 0
        blind = False
        for a in state.active:
            if a.present:
                present |= kind_bit(a.kind)
                present_eq |= equalizer_bit(a.kind)
            if a.latched:
                unacked |= kind_bit(a.kind)
                unacked_eq |= equalizer_bit(a.kind)
        for a in state.active + state.hidden:
            if a.present and a.kind in VOUCH_KINDS:
                blind = True
        self.present_bits, self.unacked_bits = present, unacked
        self.present_eq, self.unacked_eq = present_eq, unacked_eq
        statuses = getattr(state, "hoist", None) or {}     # node -> HoistStatus (AlarmState.hoist)
        for n in self.nodes:
            self.standing[n] = standing_of(statuses.get(n))
        self.vouched = not blind and all(n in self.latest for n in self.nodes)
        if self._tick:
            self._tick = False
            if self.vouched:
                self.heartbeat = (self.heartbeat + 1) & 0xFFFF
            self.changed("tick", None)
        else:
            self.changed("alarms", None)

    def changed(self, what: str, values: NodeValues | None) -> None:
        """Override: `what` is "frame" (with the node's new values), "tick" or "alarms"."""
