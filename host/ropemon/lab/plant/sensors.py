"""The node's inputs as its ADCs and counters read them, with injectable faults.

From the truth at the node's sample times: 4-20 mA pressure transmitters at the
taps (noise, NAMUR NE43 output limits 3.8..20.5 mA, ADC quantisation), piston
displacement transmitters, the signed up/down speed pulse counter (mod 2**16,
positive = cage going down), the double Hall sensor over the shaft marks, the
battery and the oil temperature input (0xFFFF when none is fitted). Channel scales
come from the site (the same numbers the node config carries, docs/config.md).

Faults (per channel and rope, over [start_s, end_s)): `open_loop` (the loop
current falls to 0 mA), `stuck` (the reading freezes), `spike` (single-sample
jumps of spike_size at spike_rate_hz, random times), `drift` (an offset growing
at drift_per_s). Sizes are in the channel's unit: Pa or m.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NAMUR_LO_MA = 3.8    # a healthy transmitter saturates here (NE43)...
NAMUR_HI_MA = 20.5   # ...and here; beyond is a failure signal
TEMP_ABSENT = 0xFFFF


@dataclass(frozen=True)
class Fault:
    KINDS = ("open_loop", "stuck", "spike", "drift")
    CHANNELS = ("pressure", "displacement")
    kind: str
    channel: str
    rope: int
    start_s: float
    end_s: float
    drift_per_s: float = 0.0
    spike_size: float = 0.0
    spike_rate_hz: float = 1.0


@dataclass(frozen=True)
class SensorSpec:
    pressure_noise_Pa: float
    displacement_noise_m: float
    adc_noise_counts: float
    battery_V: float
    battery_drain_V_per_h: float
    battery_noise_V: float
    temperature_noise_C: float
    hall_half_width_m: float
    hall_spacing_m: float
    faults: tuple[Fault, ...] = ()


def _apply_faults(values: np.ndarray, t: np.ndarray, faults, channel: str, rng) -> tuple[np.ndarray, np.ndarray]:
    """Faulted physical values (K, N) and a mask of open loops."""
    out = values.copy()
    open_loop = np.zeros(values.shape, dtype=bool)
    for f in faults:
        if f.channel != channel:
            continue
        m = (t >= f.start_s) & (t < f.end_s)
        if not m.any():
            continue
        col = out[:, f.rope]
        if f.kind == "open_loop":
            open_loop[m, f.rope] = True
        elif f.kind == "stuck":
            col[m] = col[np.argmax(m)]
        elif f.kind == "drift":
            col[m] += f.drift_per_s * (t[m] - f.start_s)
        elif f.kind == "spike":
            hz = 1.0 / (t[1] - t[0]) if len(t) > 1 else 1.0
            hit = m & (rng.random(len(t)) < f.spike_rate_hz / hz)
            col[hit] += f.spike_size
    return out, open_loop


def _adc(counts: np.ndarray, spec: SensorSpec, full: int, rng) -> np.ndarray:
    if spec.adc_noise_counts > 0:
        counts = counts + rng.normal(0.0, spec.adc_noise_counts, counts.shape)
    return np.clip(np.rint(counts), 0, full).astype(np.uint16)


def sensor_records(spec: SensorSpec, physical: dict, t: np.ndarray, truth: dict, rng) -> np.ndarray:
    """The .rsens records (K, 2N + 4) of u16 (docs/data-formats.md) from truth at the sample times t."""
    n = physical["ropes"]
    full = (1 << physical["adc_bits"]) - 1
    K = len(t)
    rec = np.zeros((K, 2 * n + 4), dtype=np.uint16)
    # pressure: p_tap -> current -> counts
    p = truth["p_tap_Pa"] + rng.normal(0.0, spec.pressure_noise_Pa, (K, n))
    p, open_p = _apply_faults(p, t, spec.faults, "pressure", rng)
    for i, ch in enumerate(physical["pressure_channels"]):
        lo, hi = ch["range_Pa"]
        ma = np.clip(4.0 + 16.0 * (p[:, i] - lo) / (hi - lo), NAMUR_LO_MA, NAMUR_HI_MA)
        ma = np.where(open_p[:, i], 0.0, ma)
        c = ch["counts_4mA"] + (ma - 4.0) / 16.0 * (ch["counts_20mA"] - ch["counts_4mA"])
        rec[:, i] = _adc(c, spec, full, rng)
    # displacement
    x = truth["piston_x_m"] + rng.normal(0.0, spec.displacement_noise_m, (K, n))
    x, open_x = _apply_faults(x, t, spec.faults, "displacement", rng)
    for i, ch in enumerate(physical["displacement_channels"]):
        lo, hi = ch["range_m"]
        c = ch["counts_lo"] + (x[:, i] - lo) / (hi - lo) * (ch["counts_hi"] - ch["counts_lo"])
        c = np.where(open_x[:, i], 0.0, c)
        rec[:, n + i] = _adc(c, spec, full, rng)
    # battery
    volts = spec.battery_V - spec.battery_drain_V_per_h * t / 3600.0 + rng.normal(0.0, spec.battery_noise_V, K)
    rec[:, 2 * n] = np.clip(np.rint(volts / physical["battery_V_per_count"]), 0, full).astype(np.uint16)
    # oil temperature
    tc = physical.get("temperature")
    if tc is None:
        rec[:, 2 * n + 1] = TEMP_ABSENT
    else:
        temp = truth["oil_temp_C"] + rng.normal(0.0, spec.temperature_noise_C, K)
        rec[:, 2 * n + 1] = np.clip(np.rint(tc["counts_at_0C"] + tc["counts_per_C"] * temp), 0, full - 1)
    # speed pulses and Hall marks from the cage depth
    depth = truth.get("cage_depth_m")
    if depth is not None:
        mpp = physical["speed_m_per_pulse"]
        pulses = np.floor(depth / mpp).astype(np.int64)
        rec[:, 2 * n + 2] = ((pulses - pulses[0]) % 65536).astype(np.uint16)
        marks = np.asarray(physical["hall_marks_m"])
        a = (np.abs(depth[:, None] - marks[None, :]) <= spec.hall_half_width_m).any(axis=1)
        b = (np.abs(depth[:, None] - spec.hall_spacing_m - marks[None, :]) <= spec.hall_half_width_m).any(axis=1)
        rec[:, 2 * n + 3] = a.astype(np.uint16) | (b.astype(np.uint16) << 1)
    return rec
