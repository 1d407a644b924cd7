"""A hoist's figures from its node configs (node.json): what the monitor's view, the alarms,
the faces and the report need to know beyond the frames.

`NodeFigures` holds them (from a checked `physical` section, `ropemon.station.physical`, or
from a node.json through its `load_node_json`); `figures_from_configs` reads the node.json files
of one hoist and refuses ones that disagree; `alarm_settings` and `equalizer_settings` turn the
figures into the alarm engine's thresholds (`ropemon.station.alarms`, `ropemon.station.equalizer`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ropemon.station.alarms import AlarmSettings
from ropemon.station.equalizer import EqualizerSettings
from ropemon.station.physical import HOST_DEFAULTS, Physical, load_node_json
from ropemon.station.protocol import DAN_TO_N
from ropemon.station.uncertainty import BandParams

@dataclass
class NodeFigures:
    """What the monitor's view and alarms need to know about the hoist beyond the frames."""

    cylinder_area_m2: list[float] = field(default_factory=list)  # per rope; empty: raw shown in kPa
    rated_rope_tension_n: float | None = None
    rated_load_n: float | None = None        # total of all ropes; default ropes x rated rope
    imbalance_frac: float = 0.10
    battery_low_v: float | None = None
    conveyance_weight_n: float | None = None  # weight of the empty cage alone; None: no slack alarm
    slack_frac: float = HOST_DEFAULTS["slack_frac"]        # slack below this share of a rope's part of conveyance_weight_n
    overload_frac: float = HOST_DEFAULTS["overload_frac"]  # overload above this share of rated_load_n
    band: BandParams | None = None           # the seal's friction lines: each rope's band (ropemon.station.uncertainty)
    stroke_m: list[float] = field(default_factory=list)  # per rope, end stops at +-stroke/2; empty: unknown
    stroke_margin_m: float | None = None     # the stroke-limit band within this of an end; None: no stroke
    hydraulic_compliance_m_per_pa: list[float] = field(default_factory=list)  # k per rope (the oil's compression); empty: none fitted
    displacement_noise_m: float | None = None  # rms per sample of the displacement channels
    samples_per_frame: int | None = None     # sample_hz / frame_hz

    @classmethod
    def from_physical(cls, p: Physical) -> "NodeFigures":
        """The figures of a checked `physical` section."""
        return cls(
            cylinder_area_m2=list(p.cylinder_area_m2),
            rated_rope_tension_n=p.rated_rope_tension_N,
            rated_load_n=p.rated_total_N,
            imbalance_frac=p.imbalance_frac,
            battery_low_v=p.battery_low_V,
            conveyance_weight_n=p.conveyance_weight_N,
            slack_frac=p.slack_frac if p.slack_frac is not None else HOST_DEFAULTS["slack_frac"],
            overload_frac=p.overload_frac if p.overload_frac is not None else HOST_DEFAULTS["overload_frac"],
            band=p.band(),
            stroke_m=list(p.stroke_m or ()),
            stroke_margin_m=p.stroke_margin,
            hydraulic_compliance_m_per_pa=list(p.oil_compliance) if any(p.oil_compliance) else [],
            displacement_noise_m=p.setting("displacement_noise_m"),
            samples_per_frame=p.sample_hz // p.frame_hz,
        )

    @classmethod
    def from_node_json(cls, path: str | Path) -> "NodeFigures":
        """The figures from a node.json's `physical` section (docs/config.md); ValueError names
        the file, the field and the reason."""
        return cls.from_physical(load_node_json(path)[0])


def figures_from_configs(paths: list[str]) -> NodeFigures:
    """The hoist's figures from its node.json files (defaults without any). The view and the
    alarms use one set of figures: node configs that disagree on them are refused."""
    figures = [(p, NodeFigures.from_node_json(p)) for p in paths]
    for p, f in figures[1:]:
        if f != figures[0][1]:
            raise ValueError(f"{p} and {figures[0][0]} describe different hoists (cylinder areas, rated "
                             "tension, loads or thresholds differ): run one monitor per hoist")
    return figures[0][1] if figures else NodeFigures()


def equalizer_settings(figures: NodeFigures) -> EqualizerSettings:
    """The equalizer alarms' figures from the node config (`ropemon.station.equalizer`): the cylinder
    areas, the stroke and its margin, and where the figures carry them the hydraulic compliance,
    the displacement channel's noise and the samples per frame; the thresholds' defaults."""
    kw: dict[str, Any] = {"areas_m2": tuple(figures.cylinder_area_m2),
                          "stroke_m": tuple(figures.stroke_m),
                          "margin_m": figures.stroke_margin_m}
    if figures.hydraulic_compliance_m_per_pa:
        kw["compliance_m_per_pa"] = tuple(figures.hydraulic_compliance_m_per_pa)
    if figures.displacement_noise_m:
        kw["displacement_noise_m"] = figures.displacement_noise_m
    if figures.samples_per_frame:
        kw["samples_per_frame"] = int(figures.samples_per_frame)
    return EqualizerSettings(**kw)


def alarm_settings(figures: NodeFigures, silent_s: float = 5.0) -> AlarmSettings:
    """Alarm thresholds from the node config's figures (regulation defaults otherwise).

    With the empty conveyance's weight (`physical.conveyance_weight_N`, written by `ropemon config`)
    the slack-rope alarm is on: a rope below `slack_frac` of its share of that load. With the seal's
    friction lines (`physical.friction`) each rope gets a band and the hoist its standing status
    (the imbalance the seals can hide). The equalizer's alarms (stroke limit, not equalizing, oil
    loss, rope adjustment) from the areas, stroke and compliance (`equalizer_settings`)."""
    kw: dict[str, Any] = dict(
        deviation_frac=figures.imbalance_frac,
        battery_low_mv=int(figures.battery_low_v * 1000) if figures.battery_low_v else None,
        silent_s=silent_s,
        overload_frac=figures.overload_frac,
        band=figures.band,
        equalizer=equalizer_settings(figures),
    )
    rated_dan = int(figures.rated_load_n / DAN_TO_N) if figures.rated_load_n else None
    n_ropes = len(figures.cylinder_area_m2)
    if figures.conveyance_weight_n and rated_dan and n_ropes:
        return AlarmSettings.from_loads(rated_dan, round(figures.conveyance_weight_n / DAN_TO_N), n_ropes,
                                        slack_frac_of_empty=figures.slack_frac, **kw)
    return AlarmSettings(rated_load_dan=rated_dan, **kw)

