"""Sparkplug B for ropemon: topics, the metrics of a hoist, payloads to and from bytes.

The station is an edge node (`spBv1.0/<group>/NBIRTH/<edge node>`), each hoist a device
(`spBv1.0/<group>/DBIRTH/<edge node>/<hoist id>`). A hoist's metrics (`hoist_metrics`):

    node<N>/rope<R>/tension   Double  kN     rope R (from 1) of cage node N; null: absent
    node<N>/rope<R>/deviation Double  %      from the mean of the node's present ropes
    node<N>/sum               Double  kN     null when a rope is absent
    node<N>/depth             Double  m
    node<N>/speed             Double  m/s
    node<N>/battery           Double  V
    node<N>/oil_temperature   Double  degC   null: no temperature input
    node<N>/status            UInt32         the frame's status bits (docs/protocol.md)
    node<N>/frame_seq         UInt64         the frame's sequence number
    node<N>/rope<R>/position  Double  mm     piston position from mid-stroke; null: no healthy
                                             displacement sample, or a version 2 node
    node<N>/rope<R>/near_retracted_end, near_extended_end
                              Boolean        within the stroke margin of that end in the window
    node<N>/hidden_imbalance  Double  %      standing status: the imbalance the seals can hide
    node<N>/standing_status   String         standing status: one line an operator reads
    alarms/present            UInt32         one bit per alarm kind (scadavalues.ALARM_KINDS)
    alarms/unacknowledged     UInt32
    alarms/equalizer_present, alarms/equalizer_unacknowledged
                              UInt32         one bit per scadavalues.EQUALIZER_KINDS
    vouched                   Boolean        the station vouches for the ropes (docs/integration.md)

The edge node's own metrics: bdSeq (Int64, as the specification asks) and Node
Control/Rebirth (Boolean), by name only. Each hoist's metrics have an alias, unique within
the edge node (`aliases`): DBIRTH carries name and alias, DDATA the alias only.
"""
from __future__ import annotations

import time
from typing import Any, Iterable

from ropemon.station.mqtt import sparkplug_b_pb2 as pb
from ropemon.station.scadavalues import STROKE_HIGH, STROKE_LOW, NodeValues

NAMESPACE = "spBv1.0"
# Sparkplug B datatypes (the specification's numbering)
INT64, UINT32, UINT64, DOUBLE, BOOLEAN, STRING = 4, 7, 8, 10, 11, 12
_FIELD = {INT64: "long_value", UINT32: "int_value", UINT64: "long_value", DOUBLE: "double_value",
          BOOLEAN: "boolean_value", STRING: "string_value"}
ROPES = 4


def topic(group: str, kind: str, edge: str, device: str | None = None) -> str:
    return f"{NAMESPACE}/{group}/{kind}/{edge}" + (f"/{device}" if device else "")


def now_ms() -> int:
    return int(time.time() * 1000)


def hoist_metrics(nodes: Iterable[int]) -> list[tuple[str, int, str | None]]:
    """(name, datatype, unit) of every metric of a hoist with these cage nodes."""
    out: list[tuple[str, int, str | None]] = []
    for n in nodes:
        for r in range(1, ROPES + 1):
            out += [(f"node{n}/rope{r}/tension", DOUBLE, "kN"), (f"node{n}/rope{r}/deviation", DOUBLE, "%")]
        out += [(f"node{n}/sum", DOUBLE, "kN"), (f"node{n}/depth", DOUBLE, "m"), (f"node{n}/speed", DOUBLE, "m/s"),
                (f"node{n}/battery", DOUBLE, "V"), (f"node{n}/oil_temperature", DOUBLE, "degC"),
                (f"node{n}/status", UINT32, None), (f"node{n}/frame_seq", UINT64, None)]
        for r in range(1, ROPES + 1):
            out += [(f"node{n}/rope{r}/position", DOUBLE, "mm"), (f"node{n}/rope{r}/near_retracted_end", BOOLEAN, None),
                    (f"node{n}/rope{r}/near_extended_end", BOOLEAN, None)]
        out += [(f"node{n}/hidden_imbalance", DOUBLE, "%"), (f"node{n}/standing_status", STRING, None)]
    return out + [("alarms/present", UINT32, None), ("alarms/unacknowledged", UINT32, None), ("vouched", BOOLEAN, None),
                  ("alarms/equalizer_present", UINT32, None), ("alarms/equalizer_unacknowledged", UINT32, None)]


def aliases(devices: dict[str, list[tuple[str, int, str | None]]]) -> dict[str, dict[str, int]]:
    """{device: {metric name: alias}}: 1, 2, ... over the devices in order, each metric in order
    (unique within the edge node, as the specification asks; the same for the same station file)."""
    out: dict[str, dict[str, int]] = {}
    n = 0
    for device, metrics in devices.items():
        out[device] = {}
        for name, _, _ in metrics:
            n += 1
            out[device][name] = n
    return out


def frame_values(v: NodeValues) -> dict[str, Any]:
    """A node's frame as metric values (None: null)."""
    n = v.node
    out: dict[str, Any] = {}
    for r in range(ROPES):
        rope = v.ropes[r] if r < len(v.ropes) else None
        t = rope.tension_dan if rope else None
        d = rope.deviation if rope else None
        out[f"node{n}/rope{r + 1}/tension"] = None if t is None else t / 100
        out[f"node{n}/rope{r + 1}/deviation"] = None if d is None else round(d * 100, 4)
    out[f"node{n}/sum"] = None if v.sum_dan is None else v.sum_dan / 100
    out[f"node{n}/depth"] = v.depth_mm / 1000
    out[f"node{n}/speed"] = v.speed_mm_s / 1000
    out[f"node{n}/battery"] = v.battery_mv / 1000
    out[f"node{n}/oil_temperature"] = v.oil_temp_c
    out[f"node{n}/status"] = v.status & 0xFFFFFFFF
    out[f"node{n}/frame_seq"] = v.seq
    positions = v.version >= 3              # a version 2 node sends no position: null
    for r in range(ROPES):
        rope = v.ropes[r] if r < len(v.ropes) else None
        out[f"node{n}/rope{r + 1}/position"] = rope.position_mm if rope is not None and positions else None
        out[f"node{n}/rope{r + 1}/near_retracted_end"] = bool(rope.stroke & STROKE_LOW) if rope and positions else None
        out[f"node{n}/rope{r + 1}/near_extended_end"] = bool(rope.stroke & STROKE_HIGH) if rope and positions else None
    return out


def add_metric(p: Any, name: str | None, datatype: int, value: Any, ts_ms: int, *, unit: str | None = None,
               historical: bool = False, alias: int | None = None) -> None:
    """One metric; `name` None: by its alias only (DDATA). The datatype is always written: the
    specification asks DDATA to leave it out (SHOULD NOT), but decoders such as Eclipse Tahu's
    read a value by it."""
    m = p.metrics.add()
    if name is not None:
        m.name = name
    if alias is not None:
        m.alias = alias
    m.datatype, m.timestamp = datatype, ts_ms
    if historical:
        m.is_historical = True
    if value is None:
        m.is_null = True
    else:
        setattr(m, _FIELD[datatype], value)
    if unit is not None:
        m.properties.keys.append("engUnit")
        pv = m.properties.values.add()
        pv.type, pv.string_value = STRING, unit


def payload(seq: int | None, ts_ms: int | None = None) -> Any:
    p = pb.Payload()
    p.timestamp = now_ms() if ts_ms is None else ts_ms
    if seq is not None:
        p.seq = seq
    return p


def decode(data: bytes) -> Any:
    p = pb.Payload()
    p.ParseFromString(data)
    return p


def metric_value(m: Any) -> Any:
    """A decoded metric's value (None when null or no value)."""
    if m.is_null:
        return None
    which = m.WhichOneof("value")
    return None if which is None else getattr(m, which)


def unit_of(m: Any) -> str | None:
    for k, v in zip(m.properties.keys, m.properties.values):
        if k == "engUnit":
            return v.string_value
    return None
