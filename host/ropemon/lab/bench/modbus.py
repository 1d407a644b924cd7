"""`ropemon bench modbus`: the Modbus TCP face under 8 hoists at 10 frames/s.

Per repeat, in the same run: the baseline station (8 hoists, alarms and logs, no face),
then the same station with the [modbus] face while a pymodbus client in another process
polls every hoist's block (100 registers, function 3) ten times a second. The figures are
the station process's CPU (every thread, the server's included) as % of one core, and the
poll latency (one read's round trip at the client). Medians over the repeats.
"""
from __future__ import annotations

import statistics
import time
from typing import Any

from ropemon.lab.bench.scada import FRAME_HZ, HOISTS, in_process, percentile, run_station
from ropemon.lab.localnet import free_port


def _poller(port: int, seconds: float, out: Any) -> None:
    from pymodbus.client import ModbusTcpClient

    from ropemon.station.modbus import HOIST_BASE, HOIST_STRIDE
    c = ModbusTcpClient("127.0.0.1", port=port, timeout=3)
    ok = c.connect()
    out.put("ready" if ok else "no connection")
    lat: list[float] = []
    errors = 0
    end = time.monotonic() + seconds
    nxt = time.monotonic()
    while time.monotonic() < end:
        for h in range(HOISTS):
            t = time.perf_counter()
            r = c.read_holding_registers(HOIST_BASE + h * HOIST_STRIDE, count=HOIST_STRIDE)
            lat.append((time.perf_counter() - t) * 1000)
            errors += r.isError()
        nxt += 0.1
        time.sleep(max(0.0, nxt - time.monotonic()))
    c.close()
    out.put((lat, errors))


def measure(quick: bool = False) -> dict:
    seconds, repeats = (4.0, 1) if quick else (15.0, 3)
    runs: list[dict[str, Any]] = []
    for _ in range(repeats):
        base = run_station("", seconds)
        port = free_port()
        sub: dict[str, Any] = {}

        def ready(faces: list) -> None:
            sub["p"], sub["q"] = in_process(_poller, port, seconds)
            assert sub["q"].get(timeout=30) == "ready"

        face = run_station(f"[modbus]\nport = {port}\n", seconds, ready)
        lat, errors = sub["q"].get(timeout=60)
        sub["p"].join(10)
        runs.append({"cpu_base": base["cpu_pct"], "cpu_modbus": face["cpu_pct"], "polls": len(lat),
                     "errors": errors, "p50_ms": percentile(lat, 0.5), "p99_ms": percentile(lat, 0.99),
                     "max_ms": max(lat) if lat else float("nan")})
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    return {"hoists": HOISTS, "frame_hz": FRAME_HZ, "seconds": seconds, "repeats": repeats,
            "median": med, "runs": runs}


def describe(f: dict) -> str:
    m = f["median"]
    return "\n".join([
        f"ropemon bench modbus: {f['hoists']} hoists x {f['frame_hz']:.0f} frames/s, {f['seconds']:.0f} s, "
        f"median of {f['repeats']} repeat(s)",
        f"  station CPU, baseline (alarms, logs, no face):     {m['cpu_base']:6.1f} % of one core",
        f"  station CPU, with the Modbus face, polled 80/s:     {m['cpu_modbus']:6.1f} % of one core "
        f"(+{m['cpu_modbus'] - m['cpu_base']:.1f})",
        f"  poll latency (100 registers, function 3):           p50 {m['p50_ms']:.2f} ms, "
        f"p99 {m['p99_ms']:.2f} ms, max {m['max_ms']:.2f} ms ({m['polls']:.0f} polls, {m['errors']:.0f} errors)",
    ])
