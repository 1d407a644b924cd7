"""The site description (SITE.toml): load, validate, and derive the `physical` config.

A site engineer describes the hoist as built (ropes, cylinders, the pipe path
from each cavity to its pressure tap, oil, sensor channels, rates, node id and
key, the friction fit file, optionally the hydraulic compliance fit file);
`load_site` turns that into a validated, immutable `Site`, and
`physical_from_site` derives the `physical` section of node.json
(docs/config.md). Every refusal names the TOML field and the reason.
The file format is documented in docs/commissioning.md and by the example
scenarios/paper-site.toml.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ropemon.station import files, tomlfields
from ropemon.station import physical as physical_section
from ropemon.station.physical import G_M_S2

# ISO 3448 viscosity grades (cSt at 40 C).
ISO_VG_GRADES = (2, 3, 5, 7, 10, 15, 22, 32, 46, 68, 100, 150, 220, 320, 460, 680, 1000, 1500)

FITTING_KINDS = ("bend", "tee", "valve", "contraction", "expansion", "custom")
BEND_STYLES = ("standard", "long")
TEE_FLOWS = ("run", "branch")
VALVE_TYPES = ("ball", "gate", "globe", "plug", "butterfly", "check-swing", "check-lift")

# Per-channel limits the node can represent (the stream words are u16).
_U16_MAX = 0xFFFF

# The stroke's defaults (docs/config.md): the margin band within this of either end stop,
# and how far beyond an end stop a displacement reading is still believed (beyond: the
# channel's fault, never a stroke limit).
STROKE_MARGIN_M = 0.01
TRAVEL_TOLERANCE_M = 0.005


class SiteError(ValueError):
    """A site file that cannot be used; the message names the field and the reason."""


# ---------------------------------------------------------------- the Site model


@dataclass(frozen=True)
class SiteHoist:
    ropes: int
    shaft_depth_m: float
    cage_mass_kg: float
    rated_payload_kg: float
    rated_rope_tension_N: float
    tail_ropes: int
    tail_rope_kg_per_m: float
    max_speed_m_s: float       # fastest hoisting speed (the node rejects larger encoder jumps)
    start_depth_m: float       # where the cage stands when the node starts (it counts depth from there)

    @property
    def empty_load_N(self) -> float:
        """Static load of the empty cage plus its tail ropes at the pithead (the paper's 185.4 kN)."""
        return (self.cage_mass_kg + self.tail_ropes * self.tail_rope_kg_per_m * self.shaft_depth_m) * G_M_S2

    @property
    def conveyance_weight_N(self) -> float:
        """Weight of the empty cage alone: the least static load the head ropes carry anywhere
        in the shaft (at the bottom the tail ropes hang on the other side of their loop)."""
        return self.cage_mass_kg * G_M_S2

    @property
    def rated_load_N(self) -> float:
        """Static load with the rated payload at the pithead."""
        return self.empty_load_N + self.rated_payload_kg * G_M_S2


@dataclass(frozen=True)
class Alarms:
    imbalance_frac: float      # node flag and host alarm: rope deviation from the mean (0.10 = +-10 %)
    overload_frac: float       # host alarm: total load above this fraction of the rated load
    slack_frac: float          # host alarm: a rope below this fraction of its share of the empty load
    battery_low_V: float


@dataclass(frozen=True)
class Cylinder:
    bore_m: float
    area_m2: float             # rod-less piston area (pi bore^2 / 4 unless given)
    stroke_m: float            # end stops at +-stroke_m/2 from mid-stroke
    max_speed_m_s: float       # largest piston speed the loss table must cover
    stroke_margin_m: float = STROKE_MARGIN_M  # the stroke-limit band: within this of either end stop


@dataclass(frozen=True)
class PipeSegment:
    length_m: float
    bore_m: float
    roughness_m: float


@dataclass(frozen=True)
class Fitting:
    kind: str                  # one of FITTING_KINDS
    bore_m: float              # bore the loss coefficient refers to (the outlet bore for contraction/expansion)
    angle_deg: float = 90.0    # bend
    style: str = "standard"    # bend: standard (r/D = 1) or long (r/D = 1.5)
    flow: str = "run"          # tee: oil goes straight through (run) or turns (branch)
    valve: str = "ball"        # valve type
    from_bore_m: float = 0.0   # contraction/expansion: upstream bore
    K: float = 0.0             # custom: constant loss coefficient


@dataclass(frozen=True)
class PipePath:
    segments: tuple[PipeSegment, ...]
    fittings: tuple[Fitting, ...]

    @property
    def length_m(self) -> float:
        return sum(s.length_m for s in self.segments)


@dataclass(frozen=True)
class SiteOil:
    iso_vg: int | None                       # ISO 3448 grade, or None when given by its two viscosities
    viscosity_40C_cSt: float
    viscosity_100C_cSt: float
    density_15C_kg_m3: float
    temp_assumed_C: float                    # what the node compensates for without a temperature input
    table_temps_C: tuple[float, ...]         # temperatures of the loss table (includes temp_assumed_C)

    def properties(self):
        """Viscosity and density against temperature (ropemon.commission.oil.Oil: one model of oil for all)."""
        from ropemon.commission.oil import Oil
        return Oil(self.viscosity_40C_cSt, self.viscosity_100C_cSt, self.density_15C_kg_m3)


@dataclass(frozen=True)
class SitePressureChannel:
    counts_4mA: int
    counts_20mA: int
    range_MPa: tuple[float, float]


@dataclass(frozen=True)
class SiteDisplacementChannel:
    counts_lo: int
    counts_hi: int
    range_m: tuple[float, float]   # the transmitter's reading at counts_lo and counts_hi
    zero_m: float = 0.0            # its reading with the piston at mid-stroke
    travel_tolerance_m: float = TRAVEL_TOLERANCE_M  # a reading beyond +-(stroke/2 + this): the channel's fault

    @property
    def range_from_mid_m(self) -> tuple[float, float]:
        """range_m from mid-stroke (x > 0: piston pulled out), as node.json's `physical` holds it."""
        return (self.range_m[0] - self.zero_m, self.range_m[1] - self.zero_m)


@dataclass(frozen=True)
class SiteTemperatureChannel:
    counts_at_0C: float
    counts_per_C: float


@dataclass(frozen=True)
class Sensors:
    adc_bits: int
    pressure: tuple[SitePressureChannel, ...]
    displacement: tuple[SiteDisplacementChannel, ...]
    speed_m_per_pulse: float
    hall_marks_m: tuple[float, ...]
    battery_V_per_count: float
    temperature: SiteTemperatureChannel | None


@dataclass(frozen=True)
class Rates:
    sample_hz: int
    frame_hz: int
    velocity_cutoff_hz: float


@dataclass(frozen=True)
class Site:
    path: Path
    name: str
    node_id: int
    key_hex: str
    hoist: SiteHoist
    alarms: Alarms
    cylinders: tuple[Cylinder, ...]          # one per rope
    pipes: tuple[PipePath, ...]              # one per rope
    oil: SiteOil
    sensors: Sensors
    rates: Rates
    friction_path: Path | None               # friction.json from `ropemon fit-friction`
    compliance_path: Path | None = None      # compliance.json from `ropemon fit-compliance` (optional)
    # [compliance] friction_play_sigmas: the node's play in rms of its noise (None: the node's
    # default, 1.45; for transmitters quieter than the default see notes/accuracy-research.md,
    # "The transmitters' noise")
    play_sigmas: float | None = None
    # [compliance] noise_follow_s: how long the node averages its transmitters' noise to
    # follow it (None: the node's default, 20 s; 0: the plays stay as commissioned)
    noise_follow_s: float | None = None

    @property
    def key(self) -> bytes:
        """The node's HMAC key ([node] key_hex or key_file): it goes into node.json's node section."""
        return bytes.fromhex(self.key_hex)

    @property
    def rated_pressure_MPa(self) -> float:
        """Cavity pressure at the rated rope tension (the most loaded cylinder)."""
        return max(self.hoist.rated_rope_tension_N / c.area_m2 for c in self.cylinders) / 1e6

    @property
    def sensor_top_MPa(self) -> float:
        """Highest pressure any transmitter reads: the node evaluates friction up to here."""
        return max(ch.range_MPa[1] for ch in self.sensors.pressure)


# ---------------------------------------------------------------- field readers


class _Table(tomlfields.Table):
    """A SITE.toml table with its dotted name (tomlfields.Table raising SiteError)."""

    def __init__(self, data: Any, name: str, error: type[Exception] = SiteError):
        super().__init__(data, name, error)


def _check_number(v: Any, name: str, **bounds) -> float:
    return tomlfields.check_number(v, name, SiteError, **bounds)


def _check_int(v: Any, name: str, **bounds) -> int:
    return tomlfields.check_int(v, name, SiteError, **bounds)


def _per_rope(t: _Table, key: str, ropes: int) -> list[_Table]:
    """One table for every rope, or an array of exactly `ropes` tables (rope order)."""
    v = t.raw(key)
    name = t.field(key)
    if isinstance(v, dict):
        return [_Table(v, name) for _ in range(ropes)]
    if isinstance(v, list):
        if len(v) != ropes:
            raise SiteError(f"{name}: must have one entry per rope ({ropes}), got {len(v)}")
        return [_Table(item, f"{name}[{i}]") for i, item in enumerate(v)]
    raise SiteError(f"{name}: must be a table or an array of {ropes} tables, got {type(v).__name__}")


def _pair(t: _Table, key: str) -> tuple[float, float]:
    return t.pair(key)


# ---------------------------------------------------------------- sections


def _hoist(t: _Table) -> SiteHoist:
    # No default for the start depth: a node that counts from a guessed depth reports a wrong
    # one all shaft long (a Hall mark only corrects a count within hall_snap_m of it).
    if "start_depth_m" not in t.data:
        raise SiteError(f"{t.field('start_depth_m')}: missing (the depth in m of the landing where the "
                        "cage stands when the node is started, e.g. the loading landing)")
    shaft = t.number("shaft_depth_m", gt=0)
    h = SiteHoist(
        ropes=t.integer("ropes", lo=1, hi=4),
        shaft_depth_m=shaft,
        cage_mass_kg=t.number("cage_mass_kg", gt=0),
        rated_payload_kg=t.number("rated_payload_kg", ge=0),
        rated_rope_tension_N=t.number("rated_rope_tension_N", gt=0),
        tail_ropes=t.integer("tail_ropes", 0, lo=0),
        tail_rope_kg_per_m=t.number("tail_rope_kg_per_m", 0.0, ge=0),
        max_speed_m_s=t.number("max_speed_m_s", gt=0, le=25),
        start_depth_m=t.number("start_depth_m", ge=-100.0, le=shaft),
    )
    t.finish()
    if h.tail_ropes and not h.tail_rope_kg_per_m > 0:
        raise SiteError(f"{t.field('tail_rope_kg_per_m')}: must be > 0 when tail_ropes = {h.tail_ropes}")
    # Every rope's share of the rated pithead load must fit under its rating, or the rating is wrong.
    share = h.rated_load_N / h.ropes
    if share > h.rated_rope_tension_N:
        raise SiteError(f"{t.field('rated_rope_tension_N')}: must be >= the rated load per rope "
                        f"{share:.0f} N (cage + payload + tail ropes), got {h.rated_rope_tension_N:g}")
    return h


def _alarms(t: _Table) -> Alarms:
    a = Alarms(
        imbalance_frac=t.number("imbalance_frac", 0.10, gt=0, lt=1),
        overload_frac=t.number("overload_frac", 1.10, gt=1),
        slack_frac=t.number("slack_frac", 0.60, gt=0, lt=1),
        battery_low_V=t.number("battery_low_V", gt=0),
    )
    t.finish()
    return a


def _cylinder(t: _Table) -> Cylinder:
    bore = t.number("bore_m", gt=0, le=1.0)
    circle = math.pi * bore * bore / 4
    area = t.number("area_m2", circle, gt=0)
    if area > circle * 1.0001:
        raise SiteError(f"{t.field('area_m2')}: must not exceed pi*bore^2/4 = {circle:.6g} m^2, got {area:g}")
    stroke = t.number("stroke_m", gt=0, le=physical_section.STROKE_MAX_M)
    margin = t.number("stroke_margin_m", STROKE_MARGIN_M, gt=0)
    if not margin < stroke / 4:
        raise SiteError(f"{t.field('stroke_margin_m')}: must be < stroke_m/4 = {stroke / 4:g} m (the margin bands "
                        f"at both ends must leave half the stroke free), got {margin:g}")
    c = Cylinder(bore_m=bore, area_m2=area, stroke_m=stroke,
                 max_speed_m_s=t.number("max_speed_m_s", gt=0, le=10), stroke_margin_m=margin)
    t.finish()
    return c


def _segment(t: _Table) -> PipeSegment:
    s = PipeSegment(length_m=t.number("length_m", gt=0), bore_m=t.number("bore_m", gt=0, le=0.5),
                    roughness_m=t.number("roughness_m", 1.5e-6, ge=0))
    t.finish()
    if s.roughness_m >= s.bore_m / 2:
        raise SiteError(f"{t.field('roughness_m')}: must be well below the bore, got {s.roughness_m:g}")
    return s


def _fitting(t: _Table, default_bore_m: float) -> Fitting:
    kind = t.string("kind", choices=FITTING_KINDS)
    bore = t.number("bore_m", default_bore_m, gt=0, le=0.5)
    kw: dict[str, Any] = {}
    if kind == "bend":
        kw["angle_deg"] = t.number("angle_deg", 90.0, gt=0, le=180)
        if kw["angle_deg"] not in (45.0, 90.0, 180.0):
            raise SiteError(f"{t.field('angle_deg')}: must be 45, 90 or 180 (bend tables), got {kw['angle_deg']:g}")
        kw["style"] = t.string("style", "standard", choices=BEND_STYLES)
        if kw["angle_deg"] == 180.0 and kw["style"] == "standard":
            raise SiteError(f"{t.field('style')}: a 180 degree bend must be 'long'")
    elif kind == "tee":
        kw["flow"] = t.string("flow", choices=TEE_FLOWS)
    elif kind == "valve":
        kw["valve"] = t.string("valve", choices=VALVE_TYPES)
    elif kind in ("contraction", "expansion"):
        kw["from_bore_m"] = t.number("from_bore_m", gt=0, le=0.5)
        if kind == "contraction" and not kw["from_bore_m"] > bore:
            raise SiteError(f"{t.field('from_bore_m')}: a contraction must come from a larger bore than "
                            f"bore_m = {bore:g}, got {kw['from_bore_m']:g}")
        if kind == "expansion" and not kw["from_bore_m"] < bore:
            raise SiteError(f"{t.field('from_bore_m')}: an expansion must come from a smaller bore than "
                            f"bore_m = {bore:g}, got {kw['from_bore_m']:g}")
    elif kind == "custom":
        kw["K"] = t.number("K", ge=0)
    t.finish()
    return Fitting(kind=kind, bore_m=bore, **kw)


def _pipe(t: _Table) -> PipePath:
    segs_raw = t.raw("segments")
    if not isinstance(segs_raw, list) or not segs_raw:
        raise SiteError(f"{t.field('segments')}: must be a non-empty array of tables")
    segments = tuple(_segment(_Table(s, f"{t.field('segments')}[{i}]")) for i, s in enumerate(segs_raw))
    fits_raw = t.raw("fittings", [])
    if not isinstance(fits_raw, list):
        raise SiteError(f"{t.field('fittings')}: must be an array of tables")
    fittings = tuple(_fitting(_Table(f, f"{t.field('fittings')}[{i}]"), segments[0].bore_m)
                     for i, f in enumerate(fits_raw))
    t.finish()
    return PipePath(segments=segments, fittings=fittings)


def _oil(t: _Table) -> SiteOil:
    from ropemon.commission.oil import VG_CST_100C

    iso_vg: int | None = None
    if t.has("iso_vg"):
        if t.has("viscosity_40C_cSt"):
            raise SiteError(f"{t.field('viscosity_40C_cSt')}: give either iso_vg or viscosity_40C_cSt, not both")
        iso_vg = t.integer("iso_vg")
        if iso_vg not in ISO_VG_GRADES:
            raise SiteError(f"{t.field('iso_vg')}: not an ISO 3448 grade ({', '.join(map(str, ISO_VG_GRADES))}), "
                            f"got {iso_vg}")
        nu40 = float(iso_vg)
        if t.has("viscosity_100C_cSt"):
            nu100 = t.number("viscosity_100C_cSt", gt=0)
        elif iso_vg in VG_CST_100C:
            nu100 = VG_CST_100C[iso_vg]
        else:
            raise SiteError(f"{t.field('viscosity_100C_cSt')}: missing: no typical value for ISO VG {iso_vg}; "
                            "give the oil's datasheet value")
    elif t.has("viscosity_40C_cSt"):
        nu40 = t.number("viscosity_40C_cSt", gt=0)
        nu100 = t.number("viscosity_100C_cSt", gt=0)
    else:
        raise SiteError(f"{t.field('iso_vg')}: missing (or give viscosity_40C_cSt and viscosity_100C_cSt)")
    if not nu100 < nu40:
        raise SiteError(f"{t.field('viscosity_100C_cSt')}: must be below the 40 C viscosity {nu40:g} cSt, "
                        f"got {nu100:g}")
    density = t.number("density_15C_kg_m3", 870.0, gt=600, lt=1200)
    assumed = t.number("temp_assumed_C", ge=-40, le=120)
    temps_raw = t.raw("table_temps_C", [0.0, 10.0, 20.0, 30.0, 40.0])
    name = t.field("table_temps_C")
    if not isinstance(temps_raw, list) or not 1 <= len(temps_raw) <= 8:
        raise SiteError(f"{name}: must be a list of 1..8 temperatures in C")
    temps = sorted({_check_number(x, name, ge=-40, le=120) for x in temps_raw} | {assumed})
    if len(temps) > 8:
        raise SiteError(f"{name}: at most 8 temperatures including temp_assumed_C, got {len(temps)}")
    t.finish()
    return SiteOil(iso_vg=iso_vg, viscosity_40C_cSt=nu40, viscosity_100C_cSt=nu100, density_15C_kg_m3=density,
                   temp_assumed_C=assumed, table_temps_C=tuple(temps))


def _counts(t: _Table, key: str, full: int) -> int:
    return t.integer(key, lo=0, hi=full)


def _pressure_channel(t: _Table, full: int) -> SitePressureChannel:
    c = SitePressureChannel(counts_4mA=_counts(t, "counts_4mA", full), counts_20mA=_counts(t, "counts_20mA", full),
                            range_MPa=_pair(t, "range_MPa"))
    t.finish()
    if not c.counts_20mA > c.counts_4mA:
        raise SiteError(f"{t.field('counts_20mA')}: must be > counts_4mA = {c.counts_4mA}, got {c.counts_20mA}")
    # NAMUR NE43 needs headroom to read 21 mA (fault) and 3.6 mA (fault) distinctly.
    span = c.counts_20mA - c.counts_4mA
    if c.counts_20mA + span // 16 > full or c.counts_4mA - span // 40 < 0:
        raise SiteError(f"{t.field('counts_20mA')}: the ADC must read 3.6..21 mA (NAMUR NE43) within "
                        f"0..{full} counts; counts_4mA={c.counts_4mA}, counts_20mA={c.counts_20mA}")
    if c.range_MPa[0] < 0:
        raise SiteError(f"{t.field('range_MPa')}: low end must be >= 0 (gauge pressure), got {c.range_MPa[0]:g}")
    return c


def _displacement_channel(t: _Table, full: int, stroke_m: float) -> SiteDisplacementChannel:
    lo_hi = dict(counts_lo=_counts(t, "counts_lo", full), counts_hi=_counts(t, "counts_hi", full),
                 range_m=_pair(t, "range_m"))
    rng = lo_hi["range_m"]
    zero = t.number("zero_m", 0.0)
    if not min(rng) <= zero <= max(rng):
        raise SiteError(f"{t.field('zero_m')}: the channel's reading at mid-stroke must be within its range_m "
                        f"{rng[0]:g}..{rng[1]:g} m, got {zero:g}")
    tol = t.number("travel_tolerance_m", TRAVEL_TOLERANCE_M, ge=0, le=stroke_m / 2)
    c = SiteDisplacementChannel(**lo_hi, zero_m=zero, travel_tolerance_m=tol)
    t.finish()
    if c.counts_hi == c.counts_lo:
        raise SiteError(f"{t.field('counts_hi')}: must differ from counts_lo")
    if c.range_m[1] - c.range_m[0] > 2 * stroke_m:
        raise SiteError(f"{t.field('range_m')}: span {c.range_m[1] - c.range_m[0]:g} m exceeds twice the "
                        f"cylinder stroke {stroke_m:g} m")
    return c


def _same_for_every_rope(values: list[float], name: str, what: str) -> None:
    """The node holds one `what` for all ropes: refuse per-rope tables that give different ones."""
    if any(v != values[0] for v in values):
        raise SiteError(f"{name}: must be the same for every rope ({what}), got "
                        f"{', '.join(f'{v:g}' for v in values)}")


def _sensors(t: _Table, ropes: int, cylinders: tuple[Cylinder, ...]) -> Sensors:
    bits = t.integer("adc_bits", 16, lo=8, hi=16)
    full = (1 << bits) - 1
    pressure = tuple(_pressure_channel(c, full) for c in _per_rope(t, "pressure", ropes))
    displacement = tuple(_displacement_channel(c, full, cylinders[i].stroke_m)
                         for i, c in enumerate(_per_rope(t, "displacement", ropes)))
    _same_for_every_rope([c.travel_tolerance_m for c in displacement], "sensors.displacement.travel_tolerance_m",
                         "one travel tolerance")
    marks_raw = t.raw("hall_marks_m")
    name = t.field("hall_marks_m")
    if not isinstance(marks_raw, list) or not marks_raw:
        raise SiteError(f"{name}: must be a non-empty list of depths in m")
    marks = tuple(_check_number(m, name, ge=0) for m in marks_raw)
    if any(b <= a for a, b in zip(marks, marks[1:])):
        raise SiteError(f"{name}: must be strictly ascending, got {list(marks)}")
    temperature = None
    if t.has("temperature"):
        tt = t.table("temperature")
        temperature = SiteTemperatureChannel(counts_at_0C=tt.number("counts_at_0C", ge=0, le=full),
                                             counts_per_C=tt.number("counts_per_C", gt=0))
        tt.finish()
    s = Sensors(adc_bits=bits, pressure=pressure, displacement=displacement,
                speed_m_per_pulse=t.number("speed_m_per_pulse", gt=0, le=1.0),
                hall_marks_m=marks, battery_V_per_count=t.number("battery_V_per_count", gt=0, le=1.0),
                temperature=temperature)
    t.finish()
    return s


def _rates(t: _Table) -> Rates:
    r = Rates(sample_hz=t.integer("sample_hz", lo=1, hi=2000), frame_hz=t.integer("frame_hz", lo=1, hi=100),
              velocity_cutoff_hz=t.number("velocity_cutoff_hz", gt=0))
    t.finish()
    if r.sample_hz % r.frame_hz:
        raise SiteError(f"{t.field('frame_hz')}: sample_hz ({r.sample_hz}) must be a multiple of it, got {r.frame_hz}")
    if not r.velocity_cutoff_hz < r.sample_hz / 2:
        raise SiteError(f"{t.field('velocity_cutoff_hz')}: must be below sample_hz/2 = {r.sample_hz / 2:g}, "
                        f"got {r.velocity_cutoff_hz:g}")
    return r


def _key_hex(t: _Table, base: Path) -> str:
    if t.has("key_hex") and t.has("key_file"):
        raise SiteError(f"{t.field('key_file')}: give either key_hex or key_file, not both")
    if t.has("key_file"):
        path = base / t.string("key_file")
        try:
            text = files.read_text(path, "key file", files.MAX_KEY_FILE, SiteError).strip()
        except SiteError as e:
            raise _file_error(t.field("key_file"), e) from None
        name = f"{t.field('key_file')} ({path})"
    else:
        text = t.string("key_hex").strip()
        name = t.field("key_hex")
    try:
        key = bytes.fromhex(text)
    except ValueError:
        raise SiteError(f"{name}: must be hexadecimal") from None
    if not 16 <= len(key) <= 32:
        raise SiteError(f"{name}: key must be 16..32 bytes, got {len(key)}")
    return key.hex()


# ---------------------------------------------------------------- public API


def parse_site(doc: dict[str, Any], path: Path | str = "SITE.toml") -> Site:
    """Validate an already parsed SITE.toml document; relative paths resolve beside `path`."""
    path = Path(path)
    base = path.parent
    top = _Table(doc, "")
    name = top.string("name", path.stem)
    node = top.table("node")
    node_id = node.integer("id", lo=0, hi=255)
    key_hex = _key_hex(node, base)
    node.finish()
    hoist = _hoist(top.table("hoist"))
    alarms = _alarms(top.table("alarms"))
    cylinders = tuple(_cylinder(t) for t in _per_rope(top, "cylinders", hoist.ropes))
    _same_for_every_rope([c.stroke_margin_m for c in cylinders], "cylinders.stroke_margin_m", "one stroke margin")
    pipes = tuple(_pipe(t) for t in _per_rope(top, "pipes", hoist.ropes))
    oil = _oil(top.table("oil"))
    sensors = _sensors(top.table("sensors"), hoist.ropes, cylinders)
    rates = _rates(top.table("rates"))
    friction_path = None
    if top.has("friction"):
        ft = top.table("friction")
        friction_path = base / ft.string("file")
        ft.finish()
    compliance_path = None
    play_sigmas = None
    noise_follow_s = None
    if top.has("compliance"):
        ct = top.table("compliance")
        compliance_path = base / ct.string("file")
        if ct.has("friction_play_sigmas"):
            play_sigmas = ct.number("friction_play_sigmas", ge=PLAY_SIGMAS_MIN, le=PLAY_SIGMAS_MAX)
        if ct.has("noise_follow_s"):
            noise_follow_s = ct.number("noise_follow_s", ge=0.0, le=NOISE_FOLLOW_MAX_S)
            if 0 < noise_follow_s < NOISE_FOLLOW_MIN_S:
                raise SiteError(f"{ct.field('noise_follow_s')}: must be 0 (off) or at least "
                                f"{NOISE_FOLLOW_MIN_S:g} s (a shorter average measures the noise too "
                                f"roughly), got {noise_follow_s:g}")
        ct.finish()
    top.finish()  # an unknown top-level table (a misspelt [compliances]) is refused, not ignored
    site = Site(path=path, name=name, node_id=node_id, key_hex=key_hex, hoist=hoist, alarms=alarms,
                cylinders=cylinders, pipes=pipes, oil=oil, sensors=sensors, rates=rates,
                friction_path=friction_path, compliance_path=compliance_path, play_sigmas=play_sigmas,
                noise_follow_s=noise_follow_s)
    # The transmitters must read 130 % of rated tension (the emergency-stop level of staged alarms).
    for i, ch in enumerate(sensors.pressure):
        if ch.range_MPa[1] < 1.3 * site.rated_pressure_MPa:
            raise SiteError(f"sensors.pressure[{i}].range_MPa: top {ch.range_MPa[1]:g} MPa is below 130 % of "
                            f"the rated-tension pressure ({1.3 * site.rated_pressure_MPa:.2f} MPa)")
    return site


def in_file(e: Exception, path: Path | str) -> SiteError:
    """`e` (a refusal naming a field) with the file it is in, when the message does not name it:
    "hoist.ropes: must be an integer, got '4' (in SITE.toml's path)"."""
    return SiteError(str(e) if str(path) in str(e) else f"{e} (in {path})")


def load_site(path: Path | str) -> Site:
    """Read and validate SITE.toml; raise SiteError naming the field and the reason."""
    path = Path(path)
    doc = tomlfields.load(path, SiteError, "SITE.toml", files.MAX_SITE_TOML)
    return parse_site(doc, path)


# ---------------------------------------------------------------- friction file

FRICTION_LINES = ("Fs", "Fc", "vs", "sigma2")


def seal_refusal(fr: dict, name: str = "friction") -> str | None:
    """Why the node cannot model the fitted seal, or None: a seal that released its force
    when the bed's piston stopped (`standstill_hold_ratio`, ropemon.commission.calibrate) is not a
    LuGre seal, and the node, which holds the seal's force at rest, would over-read there.
    A fit without the figure (no standstill in its record) is not refused."""
    from ropemon.commission.calibrate import MIN_STANDSTILL_HOLD

    ratio = fr.get("standstill_hold_ratio")
    if ratio is None:
        return None
    ratio = _check_number(ratio, f"{name}.standstill_hold_ratio")
    if ratio >= MIN_STANDSTILL_HOLD:
        return None
    return (f"{name}.standstill_hold_ratio: the seal held {round(ratio * 100)} % of its sliding force when "
            f"the test bed's piston stopped (at least {round(MIN_STANDSTILL_HOLD * 100)} % needed; a LuGre seal holds "
            "nearly all of it): it does not follow the node's friction model, whose seal holds its force "
            "at rest, so the node would over-read every rope at rest; refused")


def check_friction(fr: Any, p_max_MPa: float, name: str = "friction", refuse_unheld: bool = True) -> dict[str, Any]:
    """Validate a friction fit (the JSON of `ropemon fit-friction`) over 0..p_max_MPa.

    Returns the parameters the node uses: each line as {"slope", "intercept"},
    sigma0 and sigma1. The line values must stay physical (Fs >= Fc > 0, vs > 0,
    sigma2 >= 0) across the whole operating pressure range, because the node
    evaluates them there (`ropemon.station.physical.friction_from_dict`, the check
    node.json's friction gets too); a fit also needs sigma1 > 0.
    """
    from ropemon.station.physical import friction_from_dict

    if isinstance(fr, dict) and refuse_unheld:
        refusal = seal_refusal(fr, name)
        if refusal:
            raise SiteError(refusal)
    out = friction_from_dict(fr, p_max_MPa, name, SiteError).to_dict()
    _check_number(fr.get("sigma1"), f"{name}.sigma1", gt=0)
    return out


def friction_residual(fr: dict[str, Any], name: str = "friction") -> dict[str, float]:
    """The fitted model's worst-level RMS residual over Fs on its test-bed record
    (`residual` of `ropemon fit-friction`), {"sliding": frac, "presliding": frac}, for the
    host's uncertainty band; empty for a fit written without it."""
    res = fr.get("residual")
    if res is None:
        return {}
    if not isinstance(res, dict):
        raise SiteError(f"{name}.residual: must be an object, got {type(res).__name__}")
    return {part: _check_number(res[f"{part}_rms_frac"], f"{name}.residual.{part}_rms_frac", ge=0)
            for part in ("sliding", "presliding") if res.get(f"{part}_rms_frac") is not None}


def _file_error(name: str, e: Exception) -> SiteError:
    """A refusal of `ropemon.station.files` worded as the field `name`'s: "name: cannot read
    PATH: why", "name: PATH is not valid JSON: why", "name: PATH: why"."""
    path, reason = getattr(e, "path", None), getattr(e, "reason", None)
    if path is None or reason is None:
        return SiteError(f"{name}: {e}")
    for lead, form in (("cannot read: ", "cannot read {path}: {rest}"),
                       ("not valid JSON: ", "{path} is not valid JSON: {rest}")):
        if reason.startswith(lead):
            return SiteError(f"{name}: " + form.format(path=path, rest=reason[len(lead):]))
    return SiteError(f"{name}: {path}: {reason}")


def _read_json(path: Path | str, name: str) -> Any:
    """A fit's JSON file (validated by the caller); `name` is the SITE.toml field naming it.
    A fit may hold NaN where a figure could not be computed (the fields used are checked)."""
    try:
        return files.read_json(path, "", files.MAX_FIT_JSON, SiteError, allow_nan=True)
    except SiteError as e:
        raise _file_error(name, e) from None


def read_friction(path: Path | str) -> Any:
    """friction.json as written by `ropemon fit-friction` (validated by the caller)."""
    return _read_json(path, "friction.file")


# ---------------------------------------------------------------- compliance file

COMPLIANCE_K_MAX = physical_section.COMPLIANCE_K_MAX  # m/Pa
# [compliance] friction_play_sigmas: the range evaluated (notes/accuracy-research.md, "Sensitivity" and
# "The transmitters' noise"); above 2 the rest play (4.5 sigma of four channels) would be
# narrower than the play of one channel
PLAY_SIGMAS_MIN, PLAY_SIGMAS_MAX = 1.2, 2.0
# [compliance] noise_follow_s: 0 (off) or this range; at 5 s each channel's noise level is
# good to about 2.5 %, at 20 s (the node's default) to about 1 % (docs/model.md)
NOISE_FOLLOW_MIN_S, NOISE_FOLLOW_MAX_S = 5.0, 600.0
# the limits of `physical` (ropemon.station.physical): rms noises, and bounce_hz at most sample_hz/8
PRESSURE_NOISE_MAX_PA = physical_section.SETTING_RANGES["pressure_noise_Pa"][1]
DISPLACEMENT_NOISE_MAX_M = physical_section.SETTING_RANGES["displacement_noise_m"][1]
BOUNCE_MIN_HZ, BOUNCE_MAX_HZ = physical_section.SETTING_RANGES["bounce_hz"][0], 1000 / 8


def read_compliance(path: Path | str) -> Any:
    """compliance.json as written by `ropemon fit-compliance` (check it with check_compliance)."""
    return _read_json(path, "compliance.file")


def check_compliance(fit: Any, ropes: int, name: str = "compliance") -> dict[str, Any]:
    """Validate a compliance fit (the JSON of `ropemon fit-compliance`) for a site of `ropes` ropes.

    Returns the keys the `physical` section takes from it: the hydraulic compliance
    k per rope (0..1e-6 m/Pa), whether the node's seal observer takes it (`observer_compliance`,
    when the fit says), the rms pressure noise (> 0 Pa) and, when the fit has
    them (fits before they were measured do not; `bounce_hz` null: not measured), the rms
    displacement noise (> 0 m) and the cage's bounce at the pithead (0.5 .. 125 Hz).
    """
    if not isinstance(fit, dict):
        raise SiteError(f"{name}: must be an object, got {type(fit).__name__}")
    key = "hydraulic_compliance_m_per_Pa"
    k = fit.get(key)
    if not isinstance(k, list):
        raise SiteError(f"{name}.{key}: missing or not a list of one k (m/Pa) per rope")
    if len(k) != ropes:
        raise SiteError(f"{name}.{key}: must have one entry per rope ({ropes}), got {len(k)}")
    ks = [_check_number(x, f"{name}.{key}[{i}]", ge=0, le=COMPLIANCE_K_MAX) for i, x in enumerate(k)]
    noise = _check_number(fit.get("pressure_noise_Pa"), f"{name}.pressure_noise_Pa", gt=0,
                          le=PRESSURE_NOISE_MAX_PA)
    out = {key: ks, "pressure_noise_Pa": noise}
    if "observer_compliance" in fit:  # fits before it was judged do not have it: the observer takes k
        if not isinstance(fit["observer_compliance"], bool):
            raise SiteError(f"{name}.observer_compliance: must be true or false, got {fit['observer_compliance']!r}")
        out["observer_compliance"] = fit["observer_compliance"]
    if "displacement_noise_m" in fit:
        out["displacement_noise_m"] = _check_number(fit["displacement_noise_m"], f"{name}.displacement_noise_m",
                                                    gt=0, le=DISPLACEMENT_NOISE_MAX_M)
    if fit.get("bounce_hz") is not None:  # null: not measured, the node keeps its default
        out["bounce_hz"] = _check_number(fit["bounce_hz"], f"{name}.bounce_hz", ge=BOUNCE_MIN_HZ, le=BOUNCE_MAX_HZ)
    return out


# ---------------------------------------------------------------- physical section


def physical_from_site(site: Site, friction: dict[str, Any] | None = None,
                       compliance: dict[str, Any] | None = None, refuse_unheld: bool = True) -> dict[str, Any]:
    """The `physical` section of node.json (docs/config.md) for this site.

    `friction` is a fit as written by `ropemon fit-friction`; when None it is read
    from the site's [friction] file. A seal the node cannot model is refused
    (`seal_refusal`) unless `refuse_unheld` is False (the evaluation, which shows
    what such a node would read). `compliance` is a fit as written by `ropemon
    fit-compliance`; when None it is read from the site's [compliance] file, and
    without either the node runs without a hydraulic compliance (the two keys are
    left out). The loss table dp_Pa[rope][temp][flow] is computed by ropemon.commission.losses
    at the oil's table temperatures. The node's id and key are not part of it: they go into
    the node section only (`ropemon config`, `site.node_id`, `site.key`).
    """
    from ropemon.commission import losses  # scipy/fluids only when a config is really built

    name = "friction"
    if friction is None:
        if site.friction_path is None:
            raise SiteError("friction.file: missing (run `ropemon fit-friction` and name its output here)")
        friction = read_friction(site.friction_path)
        name = f"friction ({site.friction_path.name})"
    # The node holds the friction lines above the highest pressure the test bed reached
    # (never extrapolates a fit beyond its data), so they are checked up to there.
    p_max = site.sensor_top_MPa
    tested = friction.get("pressure_range_MPa") if isinstance(friction, dict) else None
    if isinstance(tested, list) and len(tested) == 2 and isinstance(tested[1], (int, float)):
        p_max = min(p_max, float(tested[1]))
    fr = check_friction(friction, p_max, name, refuse_unheld)
    cname = "compliance"
    if compliance is None and site.compliance_path is not None:
        compliance = read_compliance(site.compliance_path)
        cname = f"compliance ({site.compliance_path.name})"
    hydraulic = {} if compliance is None else check_compliance(compliance, site.hoist.ropes, cname)
    s = site.sensors
    table = losses.loss_table(site)
    physical = {
        "ropes": site.hoist.ropes,
        "sample_hz": site.rates.sample_hz,
        "frame_hz": site.rates.frame_hz,
        "rated_rope_tension_N": site.hoist.rated_rope_tension_N,
        "imbalance_frac": site.alarms.imbalance_frac,
        "battery_low_V": site.alarms.battery_low_V,
        "cylinder_area_m2": [c.area_m2 for c in site.cylinders],
        "adc_bits": s.adc_bits,
        "pressure_channels": [{"counts_4mA": c.counts_4mA, "counts_20mA": c.counts_20mA,
                               "range_Pa": [c.range_MPa[0] * 1e6, c.range_MPa[1] * 1e6]} for c in s.pressure],
        # range_m from mid-stroke: the transmitter's zero_m folded in (docs/config.md)
        "displacement_channels": [{"counts_lo": c.counts_lo, "counts_hi": c.counts_hi,
                                   "range_m": list(c.range_from_mid_m)} for c in s.displacement],
        "stroke_m": [c.stroke_m for c in site.cylinders],
        "stroke_margin_m": site.cylinders[0].stroke_margin_m,
        "travel_tolerance_m": s.displacement[0].travel_tolerance_m,
        "speed_m_per_pulse": s.speed_m_per_pulse,
        "hall_marks_m": list(s.hall_marks_m),
        "start_depth_m": site.hoist.start_depth_m,
        "battery_V_per_count": s.battery_V_per_count,
        "temperature": (None if s.temperature is None else
                        {"counts_at_0C": s.temperature.counts_at_0C, "counts_per_C": s.temperature.counts_per_C}),
        "oil_temp_assumed_C": site.oil.temp_assumed_C,
        "velocity_cutoff_hz": site.rates.velocity_cutoff_hz,
        "piston_speed_max_m_s": max(c.max_speed_m_s for c in site.cylinders),
        "hoist_speed_max_m_s": site.hoist.max_speed_m_s,
        # Host-only (the node ignores them, node section and CRC unchanged): the slack-rope alarm
        # floor is slack_frac of each rope's share of the empty conveyance's weight (the Quebec
        # rule); overload is the total load above overload_frac of the rated load at the pithead.
        "conveyance_weight_N": site.hoist.conveyance_weight_N,
        "slack_frac": site.alarms.slack_frac,
        "rated_load_N": site.hoist.rated_load_N,
        "overload_frac": site.alarms.overload_frac,
        "friction": fr,
        "friction_p_max_MPa": p_max,
        "loss": table,
        # LuGre position x_h = k p_l + b (docs/model.md); absent: the node runs without compliance
        **hydraulic,
    }
    residual = friction_residual(friction, name)
    if residual:
        physical["friction_residual_frac"] = residual
    if site.play_sigmas is not None and hydraulic:
        physical["friction_play_sigmas"] = site.play_sigmas
    if site.noise_follow_s is not None and hydraulic:
        physical["noise_follow_s"] = site.noise_follow_s
    # What `ropemon config` writes is checked by the code the station and the node's
    # builder read it with (ropemon.station.physical).
    checked = _checked_physical(physical, site)
    # A seal stiffer in pre-sliding than the node can represent (e.g. a fit of a seal
    # with no measurable pre-sliding) is commissioned at the node's stiffest sigma0;
    # `ropemon config` warns about it (config_cli.site_warnings).
    from ropemon.commission.nodejson import sigma0_max

    s0_max = sigma0_max(checked)
    if fr["sigma0"] > s0_max:  # sigma1 keeps its ratio to sigma0 (the bristle damping time)
        physical["friction"] = dict(fr, sigma0=s0_max, sigma1=fr["sigma1"] * s0_max / fr["sigma0"])
        checked = _checked_physical(physical, site)
    return checked.to_dict()


def _checked_physical(physical: dict[str, Any], site: Site) -> "physical_section.Physical":
    try:
        return physical_section.Physical.from_dict(physical)
    except physical_section.PhysicalError as e:
        raise SiteError(f"{e} (node config built from {site.path})") from None
