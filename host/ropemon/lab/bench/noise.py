"""`ropemon bench noise`: valid frames corrupted at random, through the station's decoder.

Is radio noise ever taken as data, or does it reach the MAC check (a false
LINK INTEGRITY alarm)? Each trial takes one of a pool of valid keyed frames
(random fields, 0..4 ropes) and damages it one way, in turn:

- `bits`: 1..8 random bit flips in the raw frame, COBS-encoded again (every one
  reaches the CRC check: the CRC's own strength);
- `burst`: 1..32 consecutive raw bytes replaced by random ones, encoded again;
- `wire`: 1..6 bytes of the COBS body replaced by random non-zero bytes (the
  delimiters kept: one body per trial; COBS or the length may catch it first);
- `noise`: a body of random non-zero bytes, of a valid frame's body length
  (version 2's or version 1's): noise that fills a frame slot.

Each trial changes the frame's bytes and sits between its own 0x00 delimiters.
Its wire bytes go through a `StreamDecoder` with the node keys and one
without, and through the batch decoder; every count must say crc_fail or
malformed, none data, none mac_fail. For comparison the same damage is done to
the frame in version 1's layout (CRC-16/CCITT-FALSE, no leading delimiter) and
held against version 1's check (COBS, length, CRC-16, version, kind): how many
such a host would have taken as data.
"""
from __future__ import annotations

import binascii
import random
import time

from cobs import cobs

from ropemon.station import protocol as P
from ropemon.station.batch import decode_bytes
from ropemon.station.decoder import StreamDecoder

L = P.L
KEYS = {1: bytes(range(16)), 2: bytes(range(100, 132))}
MODES = ("bits", "burst", "wire", "noise")
V1_BODY_LENS = [P.V1_FIXED_LEN + P.V1_ROPE_LEN * n + 1 for n in range(L.MAX_ROPES + 1)]
# the body lengths of every layout the host decodes (versions 2 and 3)
V2_BODY_LENS = [L.frame_len(n, v) + 1 for v in L.VERSIONS for n in range(L.MAX_ROPES + 1)]


def frame_pool(rng: random.Random, count: int) -> list[tuple[bytes, bytes]]:
    """(version 2 raw, the same frame in version 1's layout) pairs, keyed, varied fields."""
    out = []
    seq = {1: 0, 2: 0}
    for _ in range(count):
        node = rng.choice((1, 2))
        seq[node] += 1
        n = rng.choice((0, 1, 2, 3, 4, 4, 4))
        ropes = []
        for _ in range(n):
            m = rng.randint(-500, 30000)
            ropes.append((m, m - rng.randint(0, 300), m + rng.randint(0, 300), rng.randint(0, 65535)))
        fields = dict(node=node, seq=seq[node], time_ms=rng.getrandbits(32), ropes=ropes,
                      depth_mm=rng.randint(-2**31, 2**31 - 1), speed_mm_s=rng.randint(-32768, 32767),
                      battery_mv=rng.randint(0, 65535), oil_temp_cc=rng.randint(-32768, 32767),
                      status=rng.choice((0, 0, L.ST_BATTERY_LOW)), key=KEYS[node])
        raw, _ = P.encode_frame(**fields)
        # version 1 had version 2's records (no positions, no stroke_mask) and a CRC-16
        v1 = bytearray(P.encode_frame(**fields, version=2)[0][:-L.CRC_LEN])
        v1[0] = 1
        v1 += binascii.crc_hqx(bytes(v1), 0xFFFF).to_bytes(2, "little")
        out.append((raw, bytes(v1)))
    return out


def _nonzero(rng: random.Random, n: int) -> bytes:
    return rng.randbytes(n).replace(b"\x00", b"\x01")


def _damage_raw(rng: random.Random, mode: str, v2: bytes, v1: bytes) -> tuple[bytes, bytes]:
    """The same damage (positions within the shorter frame) to both layouts; both changed."""
    n = len(v1)
    while True:
        a, b = bytearray(v2), bytearray(v1)
        if mode == "bits":
            for _ in range(rng.randint(1, 8)):
                i, bit = rng.randrange(n), 1 << rng.randrange(8)
                a[i] ^= bit
                b[i] ^= bit
        else:
            k = rng.randint(1, 32)
            at = rng.randrange(n - k + 1) if k <= n else 0
            junk = rng.randbytes(min(k, n))
            a[at:at + len(junk)] = junk
            b[at:at + len(junk)] = junk
        if a != v2 and b != v1:
            return bytes(a), bytes(b)


def _damage_body(rng: random.Random, body: bytes) -> bytes:
    while True:
        x = bytearray(body)
        for _ in range(rng.randint(1, 6)):
            x[rng.randrange(len(x))] = rng.randint(1, 255)
        if x != body:
            return bytes(x)


def corrupted_wires(frames: int, seed: int = 1) -> tuple[bytes, list[bytes], dict[str, int]]:
    """(version 2 stream, version 1 bodies, trials per mode): `frames` damaged frames,
    each between its own delimiters in the stream (0x00 + body + 0x00)."""
    rng = random.Random(seed)
    pool = frame_pool(rng, min(frames, 2000) or 1)
    wires: list[bytes] = []
    v1_bodies: list[bytes] = []
    per_mode = dict.fromkeys(MODES, 0)
    for t in range(frames):
        mode = MODES[t % len(MODES)]
        per_mode[mode] += 1
        v2, v1 = pool[rng.randrange(len(pool))]
        if mode in ("bits", "burst"):
            a, b = _damage_raw(rng, mode, v2, v1)
            body2, body1 = cobs.encode(a), cobs.encode(b)
        elif mode == "wire":
            body2, body1 = _damage_body(rng, cobs.encode(v2)), _damage_body(rng, cobs.encode(v1))
        else:
            body2 = body1 = _nonzero(rng, rng.choice(V2_BODY_LENS + V1_BODY_LENS))
        wires.append(b"\x00" + body2 + b"\x00")
        v1_bodies.append(body1)
    return b"".join(wires), v1_bodies, per_mode


def version_1_takes(body: bytes) -> bool:
    """Would a version 1 host (CRC-16) have taken this body as a data or status frame (no keys)?"""
    try:
        raw = cobs.decode(body)
    except cobs.DecodeError:
        return False
    if P.old_version(raw) != 1:  # version 1's length, version byte and CRC-16
        return False
    n_ropes = (len(raw) - P.V1_FIXED_LEN) // P.V1_ROPE_LEN
    return raw[1] == (L.KIND_DATA if n_ropes else L.KIND_STATUS)


def reaches_crc(body: bytes) -> bool:
    """The body COBS-decodes to a length the decoder checks the CRC-32 of (MIN..MAX_RAW_LEN)."""
    try:
        n = len(cobs.decode(body))
    except cobs.DecodeError:
        return False
    return P.MIN_RAW_LEN <= n <= P.MAX_RAW_LEN


def trial(frames: int, seed: int = 1, batch: bool = True) -> dict:
    """Counts of `frames` damaged frames through the decoders (see the module docstring)."""
    t0 = time.perf_counter()
    data, v1_bodies, per_mode = corrupted_wires(frames, seed)
    t_make = time.perf_counter() - t0
    out: dict = {"frames": frames, "seed": seed, "per_mode": per_mode}
    t0 = time.perf_counter()
    for name, keys in (("keyed", KEYS), ("unkeyed", None)):
        dec = StreamDecoder(keys)
        got = dec.feed(data)
        dec.finish()
        out[name] = dict(dec.counts.as_dict(), data=len(got))
        if batch:
            b = decode_bytes(data, keys)
            out[name + "_batch"] = dict(b.counts.as_dict(), data=len(b))
    t_decode = time.perf_counter() - t0
    bodies = [b for b in data.split(b"\x00") if b]
    out["reached_crc_check"] = sum(map(reaches_crc, bodies))
    out["version_1_taken_as_data"] = sum(map(version_1_takes, v1_bodies))
    out["seconds_make"] = round(t_make, 2)
    out["seconds_decode"] = round(t_decode, 2)
    return out


def measure(quick: bool = False) -> dict:
    return trial(20_000 if quick else 1_000_000, seed=1, batch=quick)


def describe(f: dict) -> str:
    k, u = f["keyed"], f["unkeyed"]
    return "\n".join([
        f"noise: {f['frames']:,} damaged frames (seed {f['seed']}; "
        + ", ".join(f"{m} {n:,}" for m, n in f["per_mode"].items()) + ")",
        f"  reached the CRC-32 check (COBS and length intact): {f['reached_crc_check']:,}",
        f"  version 2, no keys:   taken as data {u['data']}, crc_fail {u['crc_fail']:,}, malformed {u['malformed']:,}",
        f"  version 2, with keys: taken as data {k['data']}, mac_fail {k['mac_fail']} (false LINK INTEGRITY), "
        f"crc_fail {k['crc_fail']:,}, malformed {k['malformed']:,}",
        f"  the same damage to version 1 frames (CRC-16): taken as data {f['version_1_taken_as_data']}",
        f"  {f['seconds_make']} s to make the frames, {f['seconds_decode']} s to decode them",
    ])
