"""What the SCADA faces (Modbus TCP, MQTT Sparkplug B) publish of one hoist, in one place.

`HoistValues` is a station listener (one per hoist) that keeps, on the station's thread,
each node's newest frame and what follows from it (per rope tension and deviation from
the mean of the node's ropes), the alarm bits (one bit per alarm kind, `ALARM_KINDS`),
and whether the station vouches for the hoist's ropes now (`vouched`): none of
`VOUCH_KINDS` present and every configured node heard. A face subclasses it and
overrides `changed(what)` to hand the values to its own thread; no heavy import here.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

from ropemon.station.link import Received
from ropemon.station.pipeline import AlarmState, Listener, StationStatus
from ropemon.station.protocol import Frame, L

#: One bit per alarm kind (bit k = ALARM_KINDS[k]); a kind not listed sets the last bit.
ALARM_KINDS = ("deviation", "deviation_possible", "overload", "slack", "sensor_fault", "sensor_stuck",
               "config_fault", "silent", "no_data", "battery_low", "pressure_noise", "node_imbalance",
               "link_integrity", "receiver_down", "station_fault", "alarm_flood", "other")
#: While any of these is present the station cannot vouch for the hoist's ropes (shelved or not).
VOUCH_KINDS = frozenset({"silent", "no_data", "receiver_down", "station_fault", "link_integrity", "config_fault"})


def kind_bit(kind: str) -> int:
    try:
        return 1 << ALARM_KINDS.index(kind)
    except ValueError:
        return 1 << (len(ALARM_KINDS) - 1)


@dataclass(frozen=True)
class RopeValue:
    tension_dan: int | None       # 1 daN = 0.01 kN; None: the rope's sensor gave no healthy sample
    deviation: float | None       # fraction of the mean of the node's present ropes; None: not computable


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


def node_values(frame: Frame, wall_s: float, station_s: float) -> NodeValues:
    present = [r.mean_dan for r in frame.ropes if r.mean_dan != L.TENSION_ABSENT]
    mean = sum(present) / len(present) if present else 0.0
    ropes = tuple(RopeValue(None, None) if r.mean_dan == L.TENSION_ABSENT
                  else RopeValue(r.mean_dan, (r.mean_dan - mean) / mean if len(present) >= 2 and mean > 0 else None)
                  for r in frame.ropes)
    return NodeValues(frame.node, frame.seq, wall_s, station_s, frame.status, frame.fault_mask, ropes,
                      frame.total_dan, frame.depth_mm, frame.speed_mm_s, frame.battery_mv, frame.oil_temp_c)


class HoistValues(Listener):
    """One hoist's values for a SCADA face (module docstring). Runs on the station's thread."""

    name = "scada values"

    def __init__(self, hoist: str, nodes: Iterable[int]) -> None:
        self.hoist = hoist
        self.nodes = tuple(sorted(nodes))
        self.latest: dict[int, NodeValues] = {}
        self.present_bits = 0
        self.unacked_bits = 0
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
        present = unacked = 0
        blind = False
        for a in state.active:
            if a.present:
                present |= kind_bit(a.kind)
            if a.latched:
                unacked |= kind_bit(a.kind)
        for a in state.active + state.hidden:
            if a.present and a.kind in VOUCH_KINDS:
                blind = True
        self.present_bits, self.unacked_bits = present, unacked
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
