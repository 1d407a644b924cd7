"""The SCADA faces' load: 8 hoists at 10 frames/s each through one station, in real time.

`run_station(face, seconds)` builds a station file of 8 hoists (one node of 4 ropes each, a
log per hoist in a temporary data_dir), starts the face asked for ("none" is the baseline:
the same station, alarms and logs, no face), feeds one frame per hoist every 0.1 s and
ticks every 0.25 s, and returns the station process's CPU time over the run (every thread:
the station's, the face's server or publisher, paho's). The clients that measure latency
run in another process, so their CPU is not the station's.
"""
from __future__ import annotations

import json
import multiprocessing as mp
import os
import tempfile
import time
from pathlib import Path
from typing import Any

HOISTS = 8
FRAME_HZ = 10.0
TICK_HZ = 4.0


def _key(i: int) -> bytes:
    return bytes((i * 7 + k) & 0xFF for k in range(16))


def station_file(tmp: Path, faces: str) -> Path:
    from ropemon.commission.nodejson import example_physical, make_node_json
    lines = ["[station]", 'data_dir = "data"', "silent_s = 2.0", f"tick_hz = {TICK_HZ}"]
    for i in range(HOISTS):
        (tmp / f"h{i}.json").write_text(json.dumps(make_node_json(example_physical(), node_id=1, key=_key(i))))
        lines += ["[[hoist]]", f'id = "h{i}"', f'configs = ["h{i}.json"]', 'receivers = { pithead = "loop://" }']
    p = tmp / "station.toml"
    p.write_text("\n".join(lines) + "\n" + faces)
    return p


def run_station(faces: str, seconds: float, ready: Any = None) -> dict[str, float]:
    """Run the load; `ready()` is called once the faces are up (to start the clients)."""
    from ropemon.station.faces import start_faces
    from ropemon.station.hoists import Station
    from ropemon.station.protocol import encode_frame
    from ropemon.station.stationfile import load_station_file

    with tempfile.TemporaryDirectory(prefix="ropemon-bench-") as d:
        tmp = Path(d)
        sf = load_station_file(station_file(tmp, faces))
        station = Station(sf)
        started = start_faces(station, sf)
        try:
            if ready is not None:
                ready(started)
            ids = list(station.hoists)
            seq = dict.fromkeys(ids, 0)
            t0 = time.monotonic()
            c0 = os.times()
            next_frame = next_tick = t0
            frames = 0
            while True:
                now = time.monotonic()
                if now - t0 >= seconds:
                    break
                if now >= next_frame:
                    for i, h in enumerate(ids):
                        seq[h] += 1
                        base = 5000 + (seq[h] % 50)
                        wire = encode_frame(node=1, seq=seq[h], key=_key(i), time_ms=seq[h] * 100,
                                            ropes=[(base + 10 * r, base - 50, base + 50, 8000) for r in range(4)],
                                            depth_mm=seq[h] * 10, speed_mm_s=1000, battery_mv=12_000)[1]
                        station.hoists[h].pipeline.feed("pithead", wire)
                        frames += 1
                    next_frame += 1.0 / FRAME_HZ
                if now >= next_tick:
                    station.step()
                    next_tick += 1.0 / TICK_HZ
                time.sleep(max(0.0, min(next_frame, next_tick) - time.monotonic()))
            c1 = os.times()
            wall = time.monotonic() - t0
        finally:
            for f in started:
                f.stop()
            station.close()
    cpu = (c1.user - c0.user) + (c1.system - c0.system)
    return {"cpu_pct": 100.0 * cpu / wall, "frames": frames, "wall_s": wall}


def in_process(target: Any, *args: Any) -> tuple[Any, Any]:
    """Start target(*args, out_queue) in a fresh process; returns (process, queue)."""
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=target, args=(*args, q), daemon=True)
    p.start()
    return p, q


def percentile(xs: list[float], q: float) -> float:
    if not xs:
        return float("nan")
    s = sorted(xs)
    return s[min(len(s) - 1, int(round(q * (len(s) - 1))))]
