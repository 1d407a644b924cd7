"""Radio model of the shaft link: cage transmitter -> pithead and mid-shaft receivers.

Each receiver hears the cage over part of the shaft. Inside its reach a frame is
lost with a probability and hit by bit errors at a rate that both grow with the
distance from the receiver, and grow again below `weak_below_m` (the paper: the
signal beyond ~500 m is weak and disturbed). Where the two reaches overlap both
receivers deliver the frame: the host sees duplicates and must merge them. A
receiver occasionally delivers a frame twice (radio retry whose ack was lost).

Bit errors are applied to the wire bytes (after COBS), so the host sees what a
real link gives it: CRC failures, broken delimiters, resynchronisation.
Deterministic for a given seed.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

import numpy as np


@dataclass(frozen=True)
class Receiver:
    """One receiver: its depth in the shaft and how far up and down it hears."""

    name: str
    depth_m: float
    reach_up_m: float
    reach_down_m: float

    def distance_m(self, depth_m: float) -> float | None:
        """Distance from the cage at `depth_m`, or None when out of reach."""
        d = depth_m - self.depth_m
        if -self.reach_up_m <= d <= self.reach_down_m:
            return abs(d)
        return None

    def reach_at(self, depth_m: float) -> float:
        """The reach in the direction of `depth_m` (scales the distance to 0..1)."""
        return self.reach_down_m if depth_m >= self.depth_m else self.reach_up_m


@dataclass(frozen=True)
class RadioParams:
    """Link budget of the shaft radio, as probabilities per frame and per bit."""

    loss_near: float = 0.01          # frame loss next to a receiver
    loss_edge: float = 0.25          # frame loss at the edge of its reach
    ber_near: float = 1e-6           # bit error rate next to a receiver
    ber_edge: float = 2e-4           # bit error rate at the edge of its reach
    weak_below_m: float = 500.0      # below this depth the whole link degrades
    weak_loss_add: float = 0.05      # extra loss probability at the shaft bottom
    weak_ber_factor: float = 3.0     # BER multiplier at the shaft bottom
    shaft_m: float = 810.0
    # A receiver delivering the same frame twice (a radio retry whose ack was lost:
    # about as likely as losing a short ack frame near a receiver). The host's decoder
    # drops such an exact copy as `duplicate`, without a link-integrity alarm.
    retry_dup: float = 0.02
    latency_s: float = 0.005         # receiver + RS485 delay per hop

    def validate(self) -> None:
        for name in ("loss_near", "loss_edge", "weak_loss_add", "retry_dup"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"radio: {name} must be a probability in [0, 1], got {v}")
        for name in ("ber_near", "ber_edge"):
            v = getattr(self, name)
            if not 0.0 <= v < 0.5:
                raise ValueError(f"radio: {name} must be in [0, 0.5), got {v}")
        if self.shaft_m <= 0:
            raise ValueError(f"radio: shaft_m must be > 0, got {self.shaft_m}")


def paper_receivers(shaft_m: float) -> tuple[Receiver, Receiver]:
    """Pithead and mid-shaft receivers as in the paper: each covers part of the
    shaft, the two overlap around 40-60 % of the depth."""
    pithead = Receiver("pithead", 0.0, 0.0, 0.6 * shaft_m)
    mid = Receiver("mid-shaft", 0.5 * shaft_m, 0.1 * shaft_m, 0.5 * shaft_m + 1.0)
    return pithead, mid


@dataclass
class Delivery:
    """Bytes one receiver puts on its RS485 line, at host time `t_s`."""

    t_s: float
    data: bytes
    frame_index: int       # which transmitted frame this came from
    bit_errors: int


@dataclass
class RadioResult:
    """What each receiver delivered, and what happened to every frame."""

    deliveries: dict[str, list[Delivery]]
    sent: int
    heard_by: list[tuple[str, ...]] = field(default_factory=list)  # per frame: receivers with an intact copy

    @property
    def lost(self) -> int:
        """Frames no receiver delivered intact."""
        return sum(1 for h in self.heard_by if not h)


def loss_probability(p: RadioParams, rx: Receiver, depth_m: float) -> float | None:
    """Frame loss probability at this receiver, None when out of reach."""
    dist = rx.distance_m(depth_m)
    if dist is None:
        return None
    x = dist / max(rx.reach_at(depth_m), 1e-9)
    loss = p.loss_near + (p.loss_edge - p.loss_near) * x * x
    return min(1.0, loss + p.weak_loss_add * _weakness(p, depth_m))


def bit_error_rate(p: RadioParams, rx: Receiver, depth_m: float) -> float:
    """Bit error rate at this receiver (log-linear in distance: a fading link)."""
    dist = rx.distance_m(depth_m)
    if dist is None:
        return 0.5
    x = dist / max(rx.reach_at(depth_m), 1e-9)
    lo = np.log(max(p.ber_near, 1e-15))
    hi = np.log(max(p.ber_edge, 1e-15))
    ber = float(np.exp(lo + (hi - lo) * x))
    return min(0.49, ber * (1.0 + (p.weak_ber_factor - 1.0) * _weakness(p, depth_m)))


def _weakness(p: RadioParams, depth_m: float) -> float:
    """0 above `weak_below_m`, rising to 1 at the shaft bottom."""
    if depth_m <= p.weak_below_m or p.shaft_m <= p.weak_below_m:
        return 0.0
    return min(1.0, (depth_m - p.weak_below_m) / (p.shaft_m - p.weak_below_m))


def flip_bits(data: bytes, ber: float, rng: np.random.Generator) -> tuple[bytes, int]:
    """`data` with each bit flipped independently with probability `ber`."""
    nbits = len(data) * 8
    n = int(rng.binomial(nbits, ber)) if ber > 0 else 0
    if n == 0:
        return data, 0
    buf = bytearray(data)
    for bit in rng.choice(nbits, size=n, replace=False):
        buf[bit >> 3] ^= 1 << (bit & 7)
    return bytes(buf), n


def transmit(
    frames: Iterable[tuple[float, float, bytes]],
    receivers: Iterable[Receiver],
    params: RadioParams | None = None,
    seed: int = 0,
) -> RadioResult:
    """Send frames (node time s, cage depth m, wire bytes) through the shaft radio.

    Returns per receiver the list of deliveries in time order. A frame counts as
    heard by a receiver only when it arrived without bit errors (the host's CRC
    rejects the others).
    """
    p = params or RadioParams()
    p.validate()
    rxs = list(receivers)
    rng = np.random.default_rng(seed)
    out: dict[str, list[Delivery]] = {r.name: [] for r in rxs}
    heard: list[tuple[str, ...]] = []
    sent = 0
    for index, (t_s, depth_m, wire) in enumerate(frames):
        sent += 1
        ok: list[str] = []
        for rx in rxs:
            loss = loss_probability(p, rx, depth_m)
            if loss is None or rng.random() < loss:
                continue
            ber = bit_error_rate(p, rx, depth_m)
            copies = 2 if rng.random() < p.retry_dup else 1
            for c in range(copies):
                data, nerr = flip_bits(wire, ber, rng)
                out[rx.name].append(Delivery(t_s + p.latency_s * (1 + c), data, index, nerr))
                if nerr == 0 and rx.name not in ok:
                    ok.append(rx.name)
        heard.append(tuple(ok))
    return RadioResult(out, sent, heard)
