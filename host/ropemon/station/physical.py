"""node.json's `physical` section, typed and checked in one place (docs/config.md).

`Physical.from_dict(d)` turns the SI section into a frozen `Physical` or refuses it
with the field and the reason (`physical.imbalance_frac: must be <= 0.5, got 0.6`): a
missing required key or an unknown one, a wrong type (a bool or a string where a number
belongs, a float where an integer does), NaN or infinity, a value outside its physical
range, a per-rope list whose length is not `ropes`, a friction line that leaves the
seal's physics (Fs >= Fc > 0, vs > 0, sigma2 >= 0) below the pressure it is held at.
`to_dict()` gives the section back (`from_dict(p.to_dict()) == p`). `load_node_json`
reads a node.json with a size limit and refuses one changed since `ropemon config` wrote it
(`check_digest`: its `sha256` covers `physical` as the node's CRC covers `node`). The node's
id and key are not here: they are `node.node_id` and `node.key` (`node_identity`).

Everything that writes or reads `physical` goes through here: `ropemon config`
(`commission.site.physical_from_site` builds one), the node section's builder
(`commission.nodejson`), the station (`station.nodefigures.NodeFigures`: the monitor's view
and its alarm thresholds, the report) and the lab's evaluation. Checked here is what is physical;
what the node's fixed point can represent is `commission.nodejson`'s to check when
it builds the integer `node` section.
"""
from __future__ import annotations

import dataclasses
import hashlib
import hmac
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ropemon.station import files, tomlfields
from ropemon.station.protocol import KEY_LEN_MAX, KEY_LEN_MIN, L
from ropemon.station.uncertainty import DEFAULTS as BAND_DEFAULTS
from ropemon.station.uncertainty import BandParams, Line

G_M_S2 = 9.81                   # gravity, m/s2: a mass's weight wherever the figures need one
MAX_NODE_JSON_BYTES = 4 << 20   # a node.json is a few tens of kB; a bigger file is not one
MAX_MARKS = 64                  # Hall marks the node holds
MAX_LOSS_TEMPS = 8              # temperature rows of the loss table
MAX_LOSS_FLOWS = 32             # flow points of the loss table
COMPLIANCE_K_MAX = 1e-6         # m/Pa
PRESSURE_STEP_MAX_PA = 1e8      # the largest plausibility limit of a pressure step that can be written
FRICTION_LINES = ("Fs", "Fc", "vs", "sigma2")


class PhysicalError(ValueError):
    """A `physical` section that cannot be used; the message names the field and the reason."""


# Defaults of the optional node settings (docs/config.md, docs/model.md). A key written in
# `physical` always wins; `Physical.setting` applies these.
NODE_DEFAULTS: dict[str, Any] = {
    "piston_speed_max_m_s": 0.2,   # velocity estimate saturates here
    "hoist_speed_max_m_s": 20.0,   # larger counter jumps are glitches
    "hall_snap_m": 2.0,            # a Hall mark snaps depth only within this distance
    "start_depth_m": 0.0,          # depth assumed at boot (pithead landing)
    # LuGre observer (docs/model.md, "LuGre"): the seal state follows a slower
    # low-pass of position, through a play of a few noise sigmas for the dissipation.
    # With a hydraulic compliance k (m/Pa per rope), that position is x_h = k p_l + b:
    # the oil's compression from the tracked pressure p_l, plus b, a slow low-pass of
    # x_f - k p_l (docs/model.md, "LuGre (noise-robust observer)").
    "friction_cutoff_hz": 1.0,     # low-pass b: 1 Hz without compliance, 0.03 Hz with
    "displacement_noise_m": 2e-5,  # rms noise of the displacement channel (transmitter + ADC)
    "friction_play_sigmas": 2.0,   # play half-width in rms noise of that position
    # the pressure tracker that gives p_l (docs/model.md): a steady-state Kalman filter of
    # the median pressure with a creep at a constant rate and the rope bounce, a damped
    # oscillator at bounce_hz (measured by fit-compliance); the process noises are the
    # spectral densities of the creep's and the bounce's random forcing
    "bounce_hz": 2.8,              # the cage's bounce at the pithead landing
    "bounce_filter_damping": 0.2,  # the tracker's oscillator (broader than the rope's own)
    "creep_q_Pa2_s3": 3e9,
    "bounce_q_Pa2_s3": 3e9,
    "pressure_noise_Pa": 5e3,      # rms noise of the pressure channel (transmitter + ADC)
    # b a running mean this long after the start (its settling from the first samples' noise is no
    # seal travel: without it a node booted at rest reads a friction the seals do not hold; the
    # piston's travel in it is not seal travel either): 0.5 s without a compliance, 2 s with
    "friction_warmup_s": 0.5,
    # balancing strokes (docs/model.md), tracked with a compliance and 2 or more ropes: the
    # low-pass of each rope's x_f - x_h and of the common motion, the threshold on the
    # former in its rms noise, the common speed below which it has no direction, and how
    # long a direction must hold before a stroke is looked for
    "stroke_cutoff_hz": 1.0,
    "stroke_sigmas": 6.5,
    "stroke_min_speed_m_s": 1e-5,
    "stroke_settle_s": 4.0,
    # slide following (docs/model.md, "Balancing strokes"): outside a stroke, of what x_h
    # takes over from e the share (|e| - lo) / (hi - lo), 0 .. 1, with lo and hi these
    # many times e's rms noise, is the piston's proven travel and goes into the seal state
    # (slide_follow false, or both sigmas 0: off; chosen on tuning seeds)
    "slide_follow": True,
    "slide_follow_lo_sigmas": 3.0,
    "slide_follow_hi_sigmas": 5.0,
    # do no harm (docs/model.md): at rest the tension keeps of the seal friction only what
    # the seal state from the piston's own travel (x_f through a play of this many times
    # x_f's rms noise) holds the same way (0: off; 3 chosen on the tuning seeds)
    "hold_play_sigmas": 3.0,
    # rest hold (docs/model.md), with a compliance: a rope is quiet while the low-pass of
    # |x_s - x_l| (x_l: a slower low-pass of x_s) stays below rest_sigmas times the
    # position noise; then b stands and the play widens to rest_play_sigmas, so the noise
    # of a long rest does not wear the seal state down (rest_sigmas 0: no rest hold)
    "rest_sigmas": 0.0,
    "rest_play_sigmas": 4.0,
    "rest_slow_cutoff_hz": 0.2,
    "rest_cutoff_hz": 0.5,
    # noise following (docs/model.md), with a compliance: the node measures each pressure
    # channel's noise (the low-pass, this slow, of |second difference|) and scales the plays
    # and the rest threshold by the median channel's over pressure_noise_Pa's (0: fixed)
    "noise_follow_s": 0.0,
    # an implausible pressure step (docs/model.md, "Channels"): a reading further than
    # pressure_step_max_Pa (default: from the rated tension and the bounce,
    # ropemon.commission.nodejson.pressure_step_max_pa) from the one before is a transmitter
    # glitch, a fault until the steps have been plausible this long
    "pressure_step_recover_s": 0.1,
}
# the defaults that change when a compliance is given
COMPLIANCE_DEFAULTS: dict[str, float] = {
    "friction_cutoff_hz": 0.03, "friction_warmup_s": 2.0, "friction_play_sigmas": 1.45,
    "rest_sigmas": 1.12, "rest_play_sigmas": 4.5, "noise_follow_s": 20.0}
# The stroke (docs/config.md): end stops at +-stroke_m/2 from mid-stroke. With `stroke_m`
# written, the node flags a piston within `stroke_margin_m` of an end (stroke_mask) and takes a
# reading beyond +-(stroke_m/2 + travel_tolerance_m) for its displacement channel's fault;
# these are the defaults of the two (`Physical.stroke_margin`, `Physical.travel_tolerance`).
STROKE_DEFAULTS = {"stroke_margin_m": 0.01, "travel_tolerance_m": 0.005}
STROKE_MAX_M = 4.0   # the node holds positions within +-2**29 um/256 (2.1 m)
# the host's alarm settings when `physical` does not name them
HOST_DEFAULTS = {"slack_frac": 0.60, "overload_frac": 1.0}

# Ranges of the optional node settings: (low, high), both inclusive; a string bound is a
# limit that depends on the rest of the section (`Physical._limit`).
SETTING_RANGES: dict[str, tuple[float, float | str]] = {
    "piston_speed_max_m_s": (1e-3, 2.0),
    "hoist_speed_max_m_s": (0.1, 50.0),
    "hall_snap_m": (0.0, 100.0),
    "start_depth_m": (-100.0, 5000.0),
    "friction_cutoff_hz": (0.001, "velocity_cutoff_hz"),
    "displacement_noise_m": (0.0, 1e-3),
    "friction_play_sigmas": (0.0, 10.0),
    "bounce_hz": (0.5, "sample_hz/8"),
    "bounce_filter_damping": (0.05, 1.0),
    "creep_q_Pa2_s3": (1e3, 1e15),
    "bounce_q_Pa2_s3": (1e3, 1e15),
    "pressure_noise_Pa": (0.0, 1e6),
    "friction_warmup_s": (0.0, 60.0),
    "rest_sigmas": (0.0, 10.0),
    "rest_play_sigmas": (0.0, 20.0),
    "noise_follow_s": (0.0, 3600.0),
    "rest_slow_cutoff_hz": (0.001, "sample_hz/2"),
    "rest_cutoff_hz": (0.001, "sample_hz/2"),
    "stroke_sigmas": (0.0, 100.0),
    "stroke_cutoff_hz": (0.01, "sample_hz/2"),
    "stroke_min_speed_m_s": (0.0, 1.0),
    "stroke_settle_s": (0.0, 300.0),
    "slide_follow_lo_sigmas": (0.0, 100.0),
    "slide_follow_hi_sigmas": (0.0, 100.0),
    "hold_play_sigmas": (0.0, 100.0),
    "pressure_step_recover_s": (0.0, 10.0),
}
# the pressure tracker's settings: its defaults are checked only where it runs (a compliance)
TRACKER_SETTINGS = ("bounce_hz", "bounce_filter_damping", "creep_q_Pa2_s3", "bounce_q_Pa2_s3")
BAND_KEYS = tuple(BAND_DEFAULTS)
# keys that are refused with their reason (no longer used)
RETIRED = {"pressure_cutoff_hz": "no longer used: the pressure tracker (bounce_hz, docs/config.md) "
                                 "replaced the pressure low-pass",
           "node_id": "not here: the node's id is `node.node_id` only, the copy the node reads "
                      "(rebuild the file with `ropemon config`)",
           "key_hex": "not here: the node's key is `node.key` only, the copy the node reads "
                      "(rebuild the file with `ropemon config`)"}


# ---------------------------------------------------------------- the parts


@dataclass(frozen=True)
class PressureChannel:
    """A 4-20 mA pressure transmitter, linear in the ADC counts."""

    counts_4mA: int
    counts_20mA: int
    range_Pa: tuple[float, float]

    @property
    def p_max_Pa(self) -> float:
        """Sensor pressure at the highest good count (21 mA, NAMUR NE43)."""
        lo, hi = self.range_Pa
        return lo + (hi - lo) * 17 / 16

    def to_dict(self) -> dict:
        return {"counts_4mA": self.counts_4mA, "counts_20mA": self.counts_20mA, "range_Pa": list(self.range_Pa)}


@dataclass(frozen=True)
class DisplacementChannel:
    """A piston position transmitter, linear in the ADC counts (x > 0: piston pulled out).
    range_m: the positions at counts_lo and counts_hi from mid-stroke (`ropemon config`
    folds SITE.toml's zero_m, the transmitter's reading at mid-stroke, into it)."""

    counts_lo: int
    counts_hi: int
    range_m: tuple[float, float]

    @property
    def m_per_count(self) -> float:
        return (self.range_m[1] - self.range_m[0]) / (self.counts_hi - self.counts_lo)

    def to_dict(self) -> dict:
        return {"counts_lo": self.counts_lo, "counts_hi": self.counts_hi, "range_m": list(self.range_m)}


@dataclass(frozen=True)
class TemperatureInput:
    """The oil temperature input, linear in the ADC counts."""

    counts_at_0C: float
    counts_per_C: float

    def to_dict(self) -> dict:
        return {"counts_at_0C": self.counts_at_0C, "counts_per_C": self.counts_per_C}


@dataclass(frozen=True)
class Friction:
    """The LuGre seal as `ropemon fit-friction` writes it: lines in the sensor pressure (MPa)."""

    Fs: Line                  # N
    Fc: Line                  # N
    vs: Line                  # m/s
    sigma2: Line              # N s/m
    sigma0: float             # N/m
    sigma1: float             # N s/m
    residual: float | None = None   # N, host only: the fit's residual for the band

    def to_dict(self) -> dict:
        d: dict[str, Any] = {k: {"slope": getattr(self, k).slope, "intercept": getattr(self, k).intercept}
                             for k in FRICTION_LINES}
        d["sigma0"] = self.sigma0
        d["sigma1"] = self.sigma1
        if self.residual is not None:
            d["residual"] = self.residual
        return d


@dataclass(frozen=True)
class LossTable:
    """Pressure loss cavity -> sensor tap: dp_Pa[rope][temp][flow] for flow >= 0 (odd in the flow)."""

    temps_C: tuple[float, ...]
    flow_m3_s: tuple[float, ...]
    dp_Pa: tuple[tuple[tuple[float, ...], ...], ...]

    def to_dict(self) -> dict:
        return {"temps_C": list(self.temps_C), "flow_m3_s": list(self.flow_m3_s),
                "dp_Pa": [[list(row) for row in rope] for rope in self.dp_Pa]}


@dataclass(frozen=True)
class ResidualFrac:
    """The friction fit's worst-level RMS residual over Fs(p), host only (for the band)."""

    sliding: float | None = None
    presliding: float | None = None

    def to_dict(self) -> dict:
        return {k: v for k, v in (("sliding", self.sliding), ("presliding", self.presliding)) if v is not None}


# ---------------------------------------------------------------- the section


@dataclass(frozen=True)
class Physical:
    """node.json's `physical` section (docs/config.md), checked. Optional keys are None when
    the section leaves them out (`setting` gives the value the node uses)."""

    ropes: int
    sample_hz: int
    frame_hz: int
    rated_rope_tension_N: float
    imbalance_frac: float
    battery_low_V: float
    cylinder_area_m2: tuple[float, ...]
    pressure_channels: tuple[PressureChannel, ...]
    displacement_channels: tuple[DisplacementChannel, ...]
    speed_m_per_pulse: float
    hall_marks_m: tuple[float, ...]
    battery_V_per_count: float
    temperature: TemperatureInput | None
    oil_temp_assumed_C: float
    velocity_cutoff_hz: float
    friction: Friction
    loss: LossTable
    adc_bits: int | None = None
    # optional node settings (NODE_DEFAULTS, COMPLIANCE_DEFAULTS)
    piston_speed_max_m_s: float | None = None
    hoist_speed_max_m_s: float | None = None
    hall_snap_m: float | None = None
    start_depth_m: float | None = None
    friction_cutoff_hz: float | None = None
    displacement_noise_m: float | None = None
    friction_play_sigmas: float | None = None
    hydraulic_compliance_m_per_Pa: tuple[float, ...] | None = None
    observer_compliance: bool | None = None    # False: the seal observer runs without k (the oil balance keeps it)
    pressure_noise_Pa: float | None = None
    bounce_hz: float | None = None
    bounce_filter_damping: float | None = None
    creep_q_Pa2_s3: float | None = None
    bounce_q_Pa2_s3: float | None = None
    friction_warmup_s: float | None = None
    rest_sigmas: float | None = None
    rest_play_sigmas: float | None = None
    noise_follow_s: float | None = None
    rest_slow_cutoff_hz: float | None = None
    rest_cutoff_hz: float | None = None
    stroke_sigmas: float | None = None
    stroke_cutoff_hz: float | None = None
    stroke_min_speed_m_s: float | None = None
    stroke_settle_s: float | None = None
    slide_follow: bool | None = None
    slide_follow_lo_sigmas: float | None = None
    slide_follow_hi_sigmas: float | None = None
    hold_play_sigmas: float | None = None
    friction_p_max_MPa: float | None = None
    pressure_step_max_Pa: float | None = None
    pressure_step_recover_s: float | None = None
    # the stroke (STROKE_DEFAULTS): per rope, m; None: not known, no stroke limit checked
    stroke_m: tuple[float, ...] | None = None
    stroke_margin_m: float | None = None
    travel_tolerance_m: float | None = None
    # host only (the node section and its CRC do not depend on them)
    friction_residual_frac: ResidualFrac | None = None
    conveyance_weight_N: float | None = None
    slack_frac: float | None = None
    rated_load_N: float | None = None
    overload_frac: float | None = None
    band_anchor: bool | None = None
    band_margin: float | None = None
    band_gain: float | None = None
    band_saturation: float | None = None
    band_anchor_travel: float | None = None
    band_blind_s: float | None = None

    # -- derived figures ----------------------------------------------------------------
    @property
    def compliance(self) -> tuple[float, ...]:
        """k per rope (m/Pa) the node's seal observer takes; zeros without a compliance, or with
        `observer_compliance` false."""
        if self.observer_compliance is False:
            return (0.0,) * self.ropes
        return self.oil_compliance

    @property
    def oil_compliance(self) -> tuple[float, ...]:
        """k per rope (m/Pa) as fitted, whether the observer takes it or not: the oil's compression
        for the equalizer's oil balance; zeros without a compliance."""
        return self.hydraulic_compliance_m_per_Pa or (0.0,) * self.ropes

    @property
    def has_compliance(self) -> bool:
        return any(self.compliance)

    def setting(self, key: str) -> Any:
        """The value the node uses for an optional setting: as written, else its default
        (the compliance's where one is given)."""
        v = getattr(self, key)
        if v is not None:
            return v
        if self.has_compliance and key in COMPLIANCE_DEFAULTS:
            return COMPLIANCE_DEFAULTS[key]
        return NODE_DEFAULTS[key]

    @property
    def stroke_margin(self) -> float | None:
        """The stroke-limit margin the node uses (m): as written, else its default; None
        without a stroke."""
        if self.stroke_m is None:
            return None
        return self.stroke_margin_m if self.stroke_margin_m is not None else STROKE_DEFAULTS["stroke_margin_m"]

    @property
    def travel_tolerance(self) -> float | None:
        """How far beyond an end stop a displacement reading is still believed (m); None
        without a stroke."""
        if self.stroke_m is None:
            return None
        return (self.travel_tolerance_m if self.travel_tolerance_m is not None
                else STROKE_DEFAULTS["travel_tolerance_m"])

    @property
    def sensor_p_max_Pa(self) -> float:
        """The highest pressure any transmitter reads (21 mA)."""
        return max(c.p_max_Pa for c in self.pressure_channels)

    @property
    def friction_p_max_Pa(self) -> float:
        """Sensor pressure above which the friction lines are held, not extrapolated."""
        if self.friction_p_max_MPa is None:
            return self.sensor_p_max_Pa
        return self.friction_p_max_MPa * 1e6

    @property
    def rated_total_N(self) -> float:
        """The rated load the overload alarm refers to: `rated_load_N`, else ropes x the rated rope tension."""
        return self.rated_load_N if self.rated_load_N is not None else self.ropes * self.rated_rope_tension_N

    def band(self) -> BandParams | None:
        """Each rope's band (ropemon.station.uncertainty)."""
        return BandParams.from_physical(self.to_dict())

    # -- dict form ----------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The section as node.json holds it; keys left out stay out."""
        out: dict[str, Any] = {}
        for f in self.__dataclass_fields__.values():
            v = getattr(self, f.name)
            if v is None and f.name != "temperature":
                continue
            if hasattr(v, "to_dict"):
                v = v.to_dict()
            elif isinstance(v, tuple):
                v = [x.to_dict() if hasattr(x, "to_dict") else x for x in v]
            out[f.name] = v
        return out

    @classmethod
    def from_dict(cls, d: Any, where: str = "physical") -> "Physical":
        """The section `d`, checked; PhysicalError `<where>.<field>: <reason>` otherwise."""
        try:
            return _parse(d, where)
        except RecursionError:
            raise PhysicalError(f"{where}: nested too deeply") from None


def as_physical(ph: "Physical | dict", where: str = "physical") -> Physical:
    """`ph` itself, or the dict checked into a Physical."""
    return ph if isinstance(ph, Physical) else Physical.from_dict(ph, where)


# ---------------------------------------------------------------- checking


def _t(data: Any, name: str) -> tomlfields.Table:
    return tomlfields.Table(data, name, PhysicalError)


def _numbers(t: tomlfields.Table, key: str, length: int | None = None, *, what: str = "numbers",
             max_len: int | None = None, **bounds) -> tuple[float, ...]:
    v = t.array(key, length=length, max_len=max_len, what=what)
    return tuple(tomlfields.check_number(x, t.field(key) + f"[{i}]", PhysicalError, **bounds)
                 for i, x in enumerate(v))


def _pressure_channel(t: tomlfields.Table, full: int) -> PressureChannel:
    c4 = t.integer("counts_4mA", lo=0, hi=full)
    c20 = t.integer("counts_20mA", lo=0, hi=full)
    if not c20 > c4:
        raise PhysicalError(f"{t.field('counts_20mA')}: must be > counts_4mA = {c4}, got {c20}")
    rng = t.pair("range_Pa")
    t.finish()
    return PressureChannel(c4, c20, rng)


def _displacement_channel(t: tomlfields.Table, full: int) -> DisplacementChannel:
    lo = t.integer("counts_lo", lo=0, hi=full)
    hi = t.integer("counts_hi", lo=0, hi=full)
    if not hi > lo:
        raise PhysicalError(f"{t.field('counts_hi')}: must be > counts_lo = {lo}, got {hi}")
    rng = t.pair("range_m")
    t.finish()
    return DisplacementChannel(lo, hi, rng)


def friction_from_dict(fr: Any, p_max_MPa: float, name: str = "physical.friction",
                       error: type[Exception] = PhysicalError) -> Friction:
    """The friction lines and sigmas of `fr` (a friction fit, or physical.friction), checked to
    stay physical over 0 .. p_max_MPa, where the node evaluates them: Fs >= Fc > 0, vs > 0,
    sigma2 >= 0; sigma0 > 0, sigma1 >= 0. Other keys of `fr` (a fit's statistics) are the caller's."""
    if not isinstance(fr, dict):
        raise error(f"{name}: must be an object, got {type(fr).__name__}")
    lines = {}
    for key in FRICTION_LINES:
        line = fr.get(key)
        if not isinstance(line, dict):
            raise error(f"{name}.{key}: missing or not an object with slope and intercept")
        lines[key] = Line(tomlfields.number(line, "intercept", f"{name}.{key}", error),
                          tomlfields.number(line, "slope", f"{name}.{key}", error))
    sigma0 = tomlfields.check_number(fr.get("sigma0"), f"{name}.sigma0", error, gt=0)
    sigma1 = tomlfields.check_number(fr.get("sigma1"), f"{name}.sigma1", error, ge=0)
    for p in (0.0, p_max_MPa):
        fs, fc, vs, s2 = (lines[k].at(p) for k in FRICTION_LINES)
        if not fc > 0:
            raise error(f"{name}.Fc: must be > 0 over 0..{p_max_MPa:.2f} MPa, is {fc:g} N at {p:g} MPa")
        if not fs >= fc:
            raise error(f"{name}.Fs: must be >= Fc over 0..{p_max_MPa:.2f} MPa, "
                        f"Fs={fs:g} < Fc={fc:g} N at {p:g} MPa")
        if not vs > 0:
            raise error(f"{name}.vs: must be > 0 over 0..{p_max_MPa:.2f} MPa, is {vs:g} m/s at {p:g} MPa")
        if not s2 >= 0:
            raise error(f"{name}.sigma2: must be >= 0 over 0..{p_max_MPa:.2f} MPa, "
                        f"is {s2:g} N s/m at {p:g} MPa")
    return Friction(lines["Fs"], lines["Fc"], lines["vs"], lines["sigma2"], sigma0, sigma1)


def _loss(t: tomlfields.Table, ropes: int) -> LossTable:
    temps = _numbers(t, "temps_C", what="temperatures in C", max_len=MAX_LOSS_TEMPS, ge=-50, le=150)
    if not temps or any(b <= a for a, b in zip(temps, temps[1:])):
        raise PhysicalError(f"{t.field('temps_C')}: must be 1..{MAX_LOSS_TEMPS} ascending temperatures")
    flows = _numbers(t, "flow_m3_s", what="flows in m^3/s", max_len=MAX_LOSS_FLOWS, ge=0)
    if not flows or flows[0] != 0 or any(b <= a for a, b in zip(flows, flows[1:])):
        raise PhysicalError(f"{t.field('flow_m3_s')}: must start at 0 and ascend, at most {MAX_LOSS_FLOWS} points")
    dp_raw = t.array("dp_Pa", length=ropes, what="one table per rope")
    dp = []
    for i, rope in enumerate(dp_raw):
        name = f"{t.field('dp_Pa')}[{i}]"
        if not isinstance(rope, list) or len(rope) != len(temps):
            raise PhysicalError(f"{name}: must have {len(temps)} temperature rows")
        rows = []
        for j, row in enumerate(rope):
            if not isinstance(row, list) or len(row) != len(flows):
                raise PhysicalError(f"{name}[{j}]: must have {len(flows)} values (one per flow)")
            rows.append(tuple(tomlfields.check_number(x, f"{name}[{j}][{k}]", PhysicalError, ge=0)
                              for k, x in enumerate(row)))
        dp.append(tuple(rows))
    t.finish()
    return LossTable(temps, flows, tuple(dp))


def _stroke(t: tomlfields.Table, kw: dict[str, Any], n: int) -> None:
    """stroke_m (per rope), stroke_margin_m and travel_tolerance_m into `kw`, checked: the
    margin bands at both ends leave half the shortest stroke free; the tolerance within
    half of it. A margin or tolerance without a stroke is refused (it would do nothing)."""
    if t.raw("stroke_m", None) is not None:
        kw["stroke_m"] = _numbers(t, "stroke_m", n, what="strokes in m, one per rope", gt=0, le=STROKE_MAX_M)
    stroke = kw.get("stroke_m")
    for key in STROKE_DEFAULTS:
        if t.raw(key, None) is not None and stroke is None:
            raise PhysicalError(f"{t.field(key)}: needs stroke_m (the cylinders' stroke, one per rope)")
    if stroke is None:
        return
    if t.raw("stroke_margin_m", None) is not None:
        kw["stroke_margin_m"] = t.number("stroke_margin_m", gt=0, lt=min(stroke) / 4)
    elif not STROKE_DEFAULTS["stroke_margin_m"] < min(stroke) / 4:
        raise PhysicalError(f"{t.field('stroke_margin_m')}: the default {STROKE_DEFAULTS['stroke_margin_m']:g} m is "
                            f"not below stroke_m/4 = {min(stroke) / 4:g} m here; give a value")
    if t.raw("travel_tolerance_m", None) is not None:
        kw["travel_tolerance_m"] = t.number("travel_tolerance_m", ge=0, le=min(stroke) / 2)


def _limit(bound: float | str, kw: dict[str, Any]) -> float:
    if not isinstance(bound, str):
        return bound
    if bound == "velocity_cutoff_hz":
        return kw["velocity_cutoff_hz"]
    if bound == "sample_hz/2":
        return kw["sample_hz"] / 2
    if bound == "sample_hz/8":
        return kw["sample_hz"] / 8
    raise AssertionError(bound)  # pragma: no cover


def _parse(d: Any, where: str) -> Physical:
    t = _t(d, where)
    for key, why in RETIRED.items():
        if key in t.data:
            raise PhysicalError(f"{t.field(key)}: {why}")
    kw: dict[str, Any] = {}
    n = kw["ropes"] = t.integer("ropes", lo=1, hi=L.MAX_ROPES)
    fs = kw["sample_hz"] = t.integer("sample_hz", lo=1, hi=1000)
    frame_hz = kw["frame_hz"] = t.integer("frame_hz", lo=1, hi=fs)
    if fs % frame_hz:
        raise PhysicalError(f"{t.field('frame_hz')}: sample_hz ({fs}) must be a multiple of it, got {frame_hz}")
    kw["rated_rope_tension_N"] = t.number("rated_rope_tension_N", ge=1e3, le=3e5)
    kw["imbalance_frac"] = t.number("imbalance_frac", gt=0, le=0.5)
    kw["battery_low_V"] = t.number("battery_low_V", gt=0, le=65)
    kw["cylinder_area_m2"] = _numbers(t, "cylinder_area_m2", n, what="areas in m^2, one per rope", ge=1e-4, le=0.1)
    bits = kw["adc_bits"] = t.integer("adc_bits", lo=8, hi=16) if t.has("adc_bits") else None
    full = (1 << (bits or 16)) - 1
    kw["pressure_channels"] = tuple(
        _pressure_channel(_t(c, f"{t.field('pressure_channels')}[{i}]"), full)
        for i, c in enumerate(t.array("pressure_channels", length=n, what="channels, one per rope")))
    kw["displacement_channels"] = tuple(
        _displacement_channel(_t(c, f"{t.field('displacement_channels')}[{i}]"), full)
        for i, c in enumerate(t.array("displacement_channels", length=n, what="channels, one per rope")))
    kw["speed_m_per_pulse"] = t.number("speed_m_per_pulse", ge=1e-5, le=10)
    marks = kw["hall_marks_m"] = _numbers(t, "hall_marks_m", what="depths in m", max_len=MAX_MARKS)
    if any(b <= a for a, b in zip(marks, marks[1:])):
        raise PhysicalError(f"{t.field('hall_marks_m')}: must be strictly ascending, got {list(marks)}")
    kw["battery_V_per_count"] = t.number("battery_V_per_count", ge=1e-6, le=1e-2)
    temp = t.raw("temperature")
    if temp is not None:
        tt = _t(temp, t.field("temperature"))
        c0 = tt.number("counts_at_0C", ge=0, le=65535)
        cpc = tt.number("counts_per_C")
        if cpc == 0:
            raise PhysicalError(f"{tt.field('counts_per_C')}: must not be 0")
        tt.finish()
        temp = TemperatureInput(c0, cpc)
    kw["temperature"] = temp
    kw["oil_temp_assumed_C"] = t.number("oil_temp_assumed_C", ge=-50, le=150)
    kw["velocity_cutoff_hz"] = t.number("velocity_cutoff_hz", ge=0.01, le=fs / 2)

    # optional node settings: what is written is checked; the defaults the node then uses too
    if t.raw("hydraulic_compliance_m_per_Pa", None) is not None:
        kw["hydraulic_compliance_m_per_Pa"] = _numbers(t, "hydraulic_compliance_m_per_Pa", n,
                                                       what="k in m/Pa, one per rope", ge=0, le=COMPLIANCE_K_MAX)
    if t.has("observer_compliance"):
        kw["observer_compliance"] = t.boolean("observer_compliance")
    k_on = any(kw.get("hydraulic_compliance_m_per_Pa") or ()) and kw.get("observer_compliance") is not False
    for key, (lo, hi) in SETTING_RANGES.items():
        if t.has(key):
            kw[key] = t.number(key, ge=lo, le=_limit(hi, kw))
        elif key not in TRACKER_SETTINGS or k_on:
            v = COMPLIANCE_DEFAULTS.get(key, NODE_DEFAULTS[key]) if k_on else NODE_DEFAULTS[key]
            if not lo <= v <= _limit(hi, kw):
                raise PhysicalError(f"{t.field(key)}: the default {v:g} is outside {lo:g}..{_limit(hi, kw):g} "
                                    "here; give a value")
    if t.has("slide_follow"):
        kw["slide_follow"] = t.boolean("slide_follow")
    _stroke(t, kw, n)

    def eff(key: str) -> Any:
        v = kw.get(key)
        return v if v is not None else (COMPLIANCE_DEFAULTS.get(key, NODE_DEFAULTS[key]) if k_on
                                        else NODE_DEFAULTS[key])

    if k_on and eff("rest_sigmas") > 0 and eff("rest_play_sigmas") < eff("friction_play_sigmas"):
        raise PhysicalError(f"{t.field('rest_play_sigmas')}: must be at least friction_play_sigmas "
                            f"({eff('friction_play_sigmas'):g}) with the rest hold on, got {eff('rest_play_sigmas'):g}")
    lo_s, hi_s = eff("slide_follow_lo_sigmas"), eff("slide_follow_hi_sigmas")
    if (lo_s or hi_s) and hi_s <= lo_s:
        raise PhysicalError(f"{t.field('slide_follow_hi_sigmas')}: {hi_s:g} must exceed "
                            f"slide_follow_lo_sigmas {lo_s:g} (both 0: off)")

    top_MPa = max(c.p_max_Pa for c in kw["pressure_channels"]) / 1e6
    if t.raw("friction_p_max_MPa", None) is not None:
        kw["friction_p_max_MPa"] = t.number("friction_p_max_MPa", ge=0.1, le=top_MPa)
    p_max_MPa = kw.get("friction_p_max_MPa") or top_MPa
    if t.raw("pressure_step_max_Pa", None) is not None:  # 0: not checked; absent: derived
        kw["pressure_step_max_Pa"] = t.number("pressure_step_max_Pa", ge=0, le=PRESSURE_STEP_MAX_PA)
    fr, fname = t.raw("friction"), t.field("friction")
    friction = friction_from_dict(fr, p_max_MPa, fname)
    tomlfields.known(fr, fname, {*FRICTION_LINES, "sigma0", "sigma1", "residual"}, PhysicalError)
    for key in FRICTION_LINES:
        tomlfields.known(fr[key], f"{fname}.{key}", {"slope", "intercept"}, PhysicalError)
    if "residual" in fr:
        friction = dataclasses.replace(friction, residual=tomlfields.number(fr, "residual", fname, PhysicalError, ge=0))
    kw["friction"] = friction
    kw["loss"] = _loss(_t(t.raw("loss"), t.field("loss")), n)

    # host only
    if t.has("friction_residual_frac"):
        rt = _t(t.raw("friction_residual_frac"), t.field("friction_residual_frac"))
        kw["friction_residual_frac"] = ResidualFrac(
            *(rt.number(part, ge=0) if rt.has(part) else None for part in ("sliding", "presliding")))
        rt.finish()
    if t.has("conveyance_weight_N"):
        kw["conveyance_weight_N"] = t.number("conveyance_weight_N", gt=0)
    if t.has("slack_frac"):
        kw["slack_frac"] = t.number("slack_frac", gt=0, lt=1)
    if t.has("rated_load_N"):
        kw["rated_load_N"] = t.number("rated_load_N", gt=0)
    if t.has("overload_frac"):  # 2: an overload alarm that never raises is no alarm
        kw["overload_frac"] = t.number("overload_frac", ge=1, le=2)
    for key in BAND_KEYS:
        if t.has(key):
            kw[key] = t.boolean(key) if isinstance(BAND_DEFAULTS[key], bool) else t.number(key)
    t.finish()
    p = Physical(**kw)
    try:  # the band's own ranges (ropemon.station.uncertainty)
        p.band()
    except ValueError as e:
        raise PhysicalError(where + str(e)[len("physical"):] if str(e).startswith("physical") else str(e)) from None
    return p


# ---------------------------------------------------------------- node.json


DIGEST = "sha256"   # node.json's digest of everything else in it (docs/config.md)


def document_digest(doc: dict) -> str:
    """SHA-256 (hex) of the canonical JSON of node.json's `doc` without its own `sha256`: keys
    sorted, no spaces, ASCII, floats as Python writes them (NaN as `NaN`: what the values mean
    is `Physical`'s to check). `ropemon config` writes it; every host reader checks it
    (`check_digest`)."""
    rest = {k: v for k, v in doc.items() if k != DIGEST}
    text = json.dumps(rest, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode()).hexdigest()


def check_digest(doc: Any, path: Path | str) -> None:
    """Refuse (PhysicalError naming `path`) a node.json whose `sha256` is missing or does not
    match its contents: `physical` (which the node never sees) and `node` were changed after
    `ropemon config` wrote them, by hand or by corruption, and are not to be trusted."""
    if not isinstance(doc, dict):
        raise PhysicalError(f"{path}: not a node config (not a JSON object)")
    given = doc.get(DIGEST)
    if not isinstance(given, str):
        raise PhysicalError(f"{path}: no `{DIGEST}`: not a node.json written by `ropemon config` (or one written "
                            "before node.json carried its digest): rebuild it with `ropemon config`")
    try:
        ok = hmac.compare_digest(document_digest(doc), given)
    except (TypeError, ValueError, RecursionError):
        ok = False
    if not ok:
        raise PhysicalError(f"{path}: changed after `ropemon config` wrote it (its `{DIGEST}` does not match "
                            "its contents: hand-edited or corrupted): not used; rebuild it with `ropemon config` "
                            "rather than editing it")


def node_identity(doc: Any, path: Path | str) -> tuple[int, bytes]:
    """(node id, key) of a node.json: its `node` section's `node_id` and `key`, the one copy,
    which the node reads too. Call `check_digest` first. PhysicalError names the fault."""
    nd = doc.get("node") if isinstance(doc, dict) else None
    if not isinstance(nd, dict):
        raise PhysicalError(f"{path}: not a node config (no `node` section)")
    node_id, key = nd.get("node_id"), nd.get("key")
    if type(node_id) is not int or not 0 <= node_id <= 255:
        raise PhysicalError(f"{path}: node.node_id: must be an integer 0..255, got {node_id!r}")
    if (not isinstance(key, list) or not KEY_LEN_MIN <= len(key) <= KEY_LEN_MAX
            or any(type(b) is not int or not 0 <= b <= 255 for b in key)):
        raise PhysicalError(f"{path}: node.key: must be {KEY_LEN_MIN}..{KEY_LEN_MAX} bytes (integers 0..255)")
    return node_id, bytes(key)


def load_node_json(path: Path | str, max_bytes: int = MAX_NODE_JSON_BYTES) -> tuple[Physical, dict]:
    """(the checked `physical` section, the whole document) of the node.json at `path`.

    PhysicalError names the file and the fault: unreadable, larger than `max_bytes` (a
    node.json is a few tens of kB; /dev/zero is not read forever), not JSON, nested too
    deeply, not a node config, changed since `ropemon config` wrote it (`check_digest`, before
    anything in it is used), or a `physical` section `Physical.from_dict` refuses."""
    path = Path(path)
    try:  # a FIFO or a directory is refused unopened (ropemon.station.files); /dev/zero is read bounded
        with files.open_file(path, "", None, PhysicalError, devices=True) as f:
            data = f.read(max_bytes + 1)
    except OSError as e:
        raise PhysicalError(f"{path}: cannot read: {e.strerror or e}") from None
    if len(data) > max_bytes:
        raise PhysicalError(f"{path}: larger than {max_bytes / (1 << 20):g} MB: not a node config")
    try:
        doc = json.loads(data)
    except RecursionError:
        raise PhysicalError(f"{path}: nested too deeply: not a node config") from None
    except (UnicodeDecodeError, ValueError) as e:
        raise PhysicalError(f"{path}: not valid JSON: {e}") from None
    if not isinstance(doc, dict) or "physical" not in doc:
        raise PhysicalError(f"{path}: not a node config (no `physical` section)")
    check_digest(doc, path)
    return Physical.from_dict(doc["physical"], f"{path}: physical"), doc
