"""Test helper: valid frames with varied fields, built by the host encoder."""
from __future__ import annotations

import random

from ropemon.station.protocol import L, decode_raw, encode_frame

KEYS = {1: bytes(range(16)), 2: bytes(range(100, 132))}


def make_frame(rng: random.Random, node: int, seq: int, key: bytes | None = None,
               n_ropes: int | None = None, mixed: bool = False) -> tuple[bytes, bytes]:
    """(raw, wire) of a random but valid frame: of layout version 3 without positions, or with
    `mixed` of version 2 or 3 (at random), version 3 with positions (some absent) and stroke bits."""
    if n_ropes is None:
        n_ropes = rng.choice([0, 1, 2, 3, 4, 4, 4])
    version = rng.choice([2, 3]) if mixed else L.VERSION
    ropes = []
    for _ in range(n_ropes):
        mean = rng.randint(-500, 30000)
        ropes.append((mean, mean - rng.randint(0, 300), mean + rng.randint(0, 300), rng.randint(0, 65535)))
        if mixed and version == 3:
            ropes[-1] += (rng.choice([L.POS_ABSENT, rng.randint(-32767, 32767)]),)
    extra = {"version": version}
    if mixed and version == 3:
        extra["stroke_mask"] = rng.choice([0, 0, rng.randint(0, 255)])
    return encode_frame(**extra,
        node=node, seq=seq, time_ms=rng.randint(0, 2**32 - 1), ropes=ropes,
        status=rng.choice([0, 0, 0, L.ST_BATTERY_LOW, L.ST_PRESSURE_FAULT | L.ST_IMBALANCE]),
        fault_mask=rng.choice([0, 0, 1, 0x0F]), depth_mm=rng.randint(-2**31, 2**31 - 1),
        speed_mm_s=rng.randint(-32768, 32767), battery_mv=rng.randint(0, 65535),
        oil_temp_cc=rng.randint(-32768, 32767), key=key,
        kind=L.KIND_DATA if n_ropes else L.KIND_STATUS)


def frame_set(seed: int, count: int, keyed: bool, mixed: bool = False) -> list[tuple[bytes, bytes]]:
    """`count` frames from nodes 1 and 2 with increasing seq per node (`mixed`: of layout
    versions 2 and 3 interleaved, `make_frame`)."""
    rng = random.Random(seed)
    out = []
    seqs = {1: rng.randint(0, 1000), 2: rng.randint(0, 2**32 - 1 - 10 * count)}
    for _ in range(count):
        node = rng.choice([1, 2])
        seqs[node] += rng.choice([1, 1, 1, 2])
        out.append(make_frame(rng, node, seqs[node], KEYS[node] if keyed else None, mixed=mixed))
    return out


def expected(raw: bytes, keyed: bool):
    return decode_raw(raw, KEYS if keyed else None)
