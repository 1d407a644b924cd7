"""`ropemon bench host`: streaming and batch decode speed against a naive decoder, same run.

The capture: frames of 4 ropes (some status frames) from two nodes with one
byte in 2000 flipped, like a deep-shaft receiver. Streaming feeds it in 4 KiB
reads (a serial port's pace) and builds Frame objects; batch decodes the whole
file into columns. The baseline is the obvious decoder: split on 0x00, then
per frame cobs.decode, binascii.crc32, and struct.unpack of header, each rope and tail
into a dict. Both consume each frame and drop it, as the live chain does (store,
alarms); a second pair keeps every frame alive, where the garbage collector's
work dominates. Figures are medians of repeats.
"""
from __future__ import annotations

import binascii
import random
import statistics
import struct
import time
from typing import Any

from cobs import cobs

from ropemon.station.batch import decode_bytes
from ropemon.station.decoder import StreamDecoder
from ropemon.station.protocol import L, encode_frame

CHUNK = 4096


def make_capture(n_frames: int, seed: int = 1) -> bytes:
    rng = random.Random(seed)
    out = []
    seq = {1: 0, 2: 0}
    for i in range(n_frames):
        node = 1 + (i & 1)
        seq[node] += 1
        if i % 500 == 499:
            ropes = []
        else:
            base = rng.randint(3000, 9000)
            ropes = [(base + rng.randint(-300, 300), base - 400, base + 400, rng.randint(4000, 12000))
                     for _ in range(L.MAX_ROPES)]
        out.append(encode_frame(node=node, seq=seq[node], time_ms=i * 100, ropes=ropes,
                                depth_mm=rng.randint(0, 810_000), speed_mm_s=rng.randint(-10000, 10000),
                                battery_mv=7400, oil_temp_cc=1850)[1])
    data = bytearray(b"".join(out))
    for _ in range(len(data) // 2000):
        data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
    return bytes(data)


def naive_decode(data: bytes, keep: list | None = None) -> int:
    """Baseline: one frame at a time, struct.unpack per record, into a dict per frame."""
    n_ok = 0
    for body in data.split(b"\x00"):
        if not body:
            continue
        try:
            raw = cobs.decode(body)
        except cobs.DecodeError:
            continue
        if len(raw) < L.FIXED_LEN or binascii.crc32(raw[:-4]) != struct.unpack("<I", raw[-4:])[0]:
            continue
        n = L.ropes_in(len(raw))
        if n < 0:
            continue
        d = dict(zip(L.HEADER_FIELDS, struct.unpack(L.HEADER_FMT, raw[:L.HEADER_LEN])))
        d["ropes"] = [dict(zip(L.ROPE_FIELDS, struct.unpack(L.ROPE_FMT, raw[L.HEADER_LEN + L.ROPE_LEN * i:
                                                                              L.HEADER_LEN + L.ROPE_LEN * (i + 1)])))
                      for i in range(n)]
        t = L.HEADER_LEN + L.ROPE_LEN * n
        d.update(zip(L.TAIL_FIELDS, struct.unpack(L.TAIL_FMT, raw[t:t + L.TAIL_LEN])))
        n_ok += 1
        if keep is not None:
            keep.append(d)
    return n_ok


def stream_decode(data: bytes, keep: list | None = None) -> int:
    """4 KiB reads through the StreamDecoder; frames dropped after use unless `keep`."""
    dec = StreamDecoder()
    n_ok = 0
    for i in range(0, len(data), CHUNK):
        frames = dec.feed(data[i:i + CHUNK])
        n_ok += len(frames)
        if keep is not None:
            keep += frames
    return n_ok


def _median_time(fn, repeats: int) -> tuple[float, Any]:
    times = []
    result = None
    for _ in range(repeats):
        t = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), result


def measure(quick: bool = False) -> dict:
    n_frames = 20_000 if quick else 200_000
    repeats = 3 if quick else 7
    data = make_capture(n_frames)
    mb = len(data) / 1e6
    t_base, n_ok = _median_time(lambda: naive_decode(data), repeats)
    t_stream, n_stream = _median_time(lambda: stream_decode(data), repeats)
    t_batch, batch = _median_time(lambda: decode_bytes(data), repeats)
    # Holding every decoded object alive (a whole file in memory) adds garbage-collector work.
    t_base_keep, _ = _median_time(lambda: naive_decode(data, []), repeats)
    t_stream_keep, _ = _median_time(lambda: stream_decode(data, []), repeats)
    if not (n_stream == len(batch) == n_ok):
        raise RuntimeError(f"decoders disagree: stream {n_stream}, batch {len(batch)}, naive {n_ok}")
    return {
        "capture_frames": n_frames,
        "capture_mb": round(mb, 3),
        "frames_ok": n_ok,
        "repeats": repeats,
        "baseline_frames_per_s": round(n_ok / t_base),
        "baseline_mb_per_s": round(mb / t_base, 2),
        "stream_frames_per_s": round(n_ok / t_stream),
        "stream_vs_baseline": round(t_base / t_stream, 2),
        "batch_mb_per_s": round(mb / t_batch, 2),
        "batch_frames_per_s": round(n_ok / t_batch),
        "batch_vs_baseline": round(t_base / t_batch, 2),
        "baseline_keep_all_frames_per_s": round(n_ok / t_base_keep),
        "stream_keep_all_frames_per_s": round(n_ok / t_stream_keep),
        "stream_keep_all_vs_baseline_keep_all": round(t_base_keep / t_stream_keep, 2),
    }


def describe(f: dict) -> str:
    return "\n".join([
        f"host decode: capture {f['capture_frames']} frames, {f['capture_mb']} MB, {f['frames_ok']} intact; "
        f"medians of {f['repeats']} repeats",
        f"  naive per-frame struct.unpack baseline: {f['baseline_frames_per_s']:>10,} frames/s  "
        f"{f['baseline_mb_per_s']:>7} MB/s",
        f"  streaming StreamDecoder (4 KiB reads):  {f['stream_frames_per_s']:>10,} frames/s  "
        f"x{f['stream_vs_baseline']} vs baseline (target >= 200,000 frames/s)",
        f"  batch decode_bytes (numpy):             {f['batch_frames_per_s']:>10,} frames/s  "
        f"{f['batch_mb_per_s']:>7} MB/s  x{f['batch_vs_baseline']} vs baseline (target >= 20 MB/s)",
        f"  keeping every decoded frame in memory: baseline {f['baseline_keep_all_frames_per_s']:,} frames/s, "
        f"streaming {f['stream_keep_all_frames_per_s']:,} frames/s "
        f"(x{f['stream_keep_all_vs_baseline_keep_all']}; garbage-collector load)",
    ])
