"""`ropemon bench opcua`: one station serving N hoists to M OPC UA clients.

8 hoists (one node of 4 ropes each), 10 frames/s per hoist (the hoists' frames spread over
the 100 ms and slipping one whole period over a run, so that they meet every phase of the
server's publishing cycle, as independent hoists do), 5 clients in their own
processes, each subscribed (publishing interval 100 ms, sampling interval 0: every change
is queued, queue size 100) to every hoist's rope 1 Tension over Basic256Sha256
Sign&Encrypt with a user. Each frame carries a unique tension, so a client's data-change
notification is matched to the moment the frame was handed to the station: the update
latency frame -> notification, reported as p50, p95, p99 and max over every notification
of every repeat, with the notifications received against those expected (frames x clients). The station's CPU is
the process CPU time of the benchmark's own process over the run (the station thread, the
OPC UA server's thread and its history thread; the clients run elsewhere).

Two setups, same address space, security, clients and values:
- station: the real path: each frame's bytes fed to the hoist's `HoistPipeline` (decode with MAC,
  merge, alarm engine, SQLite log), its listener handing the frame to the server's loop;
  the station steps at tick_hz as `ropemon serve` does;
- baseline: the asyncua server of the same face, written the same values with no station
  (frames decoded beforehand and handed straight to the server's loop).
Latency percentiles pool the repeats' notifications; CPU is the median over repeats; the
ratios are station / baseline.
"""
from __future__ import annotations

import asyncio
import math
import multiprocessing as mp
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from ropemon.lab.localnet import free_port

HOISTS, CLIENTS, RATE_HZ, ROPES = 8, 5, 10.0, 4
PUBLISH_MS, SAMPLING_MS, QUEUE = 100.0, 0.0, 100
WATCHDOG_S = 10.0
KEY = bytes(range(16))
USER, PASSWORD = "bench", "bench-password-1"
CLIENT_URI = "urn:ropemon:bench-client"


def _tension(i: int) -> int:
    """The unique rope-1 tension (daN) of frame i of a hoist."""
    return 3000 + i % 20000


# -- the clients (own processes) ---------------------------------------------------------


def _client(url: str, server_cert: str, cert: str, key: str, hoists: list[str], ready: Any, stop: Any,
            out: Any) -> None:
    import logging
    logging.getLogger("asyncua").setLevel(logging.ERROR)
    asyncio.run(_client_main(url, server_cert, cert, key, hoists, ready, stop, out))


async def _client_main(url: str, server_cert: str, cert: str, key: str, hoists: list[str], ready: Any,
                       stop: Any, out: Any) -> None:
    from asyncua import Client, ua
    from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

    got: list[tuple[str, int, float]] = []
    # asyncua's client probes the server every watchdog_intervall s and, when a probe takes
    # longer than that, drops the connection as lost: at the default 1 s the shared 2-core
    # machine's load lost whole clients; 10 s keeps them (the latency is measured anyway)
    c = Client(url, timeout=30, watchdog_intervall=WATCHDOG_S)
    c.application_uri = CLIENT_URI
    c.set_user(USER)
    c.set_password(PASSWORD)
    await c.set_security(SecurityPolicyBasic256Sha256, cert, key, server_certificate=server_cert,
                         mode=ua.MessageSecurityMode.SignAndEncrypt)
    await c.connect()
    try:
        idx = await c.get_namespace_index("urn:ropemon:opcua")
        nodes = {ua.NodeId(f"{h}.n1.r1.Tension", idx): h for h in hoists}

        class Handler:
            def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
                if val is not None:
                    got.append((nodes[node.nodeid], round(val * 100), time.monotonic()))

        sub = await c.create_subscription(ua.CreateSubscriptionParameters(
            RequestedPublishingInterval=PUBLISH_MS, RequestedLifetimeCount=10000, RequestedMaxKeepAliveCount=1000,
            MaxNotificationsPerPublish=0, PublishingEnabled=True), Handler())
        await sub.subscribe_data_change([c.get_node(n) for n in nodes], sampling_interval=SAMPLING_MS, queuesize=QUEUE)
        ready.put(os.getpid())
        while not stop.is_set():
            await asyncio.sleep(0.05)
        await sub.delete()
    finally:
        await c.disconnect()
    out.put(got)


# -- the setups ------------------------------------------------------------------------


def _write_station(d: Path, port: int) -> Path:
    import json

    from ropemon.commission.nodejson import example_physical, make_node_json
    from ropemon.station.users import add_user

    (d / "node.json").write_text(json.dumps(make_node_json(example_physical(), node_id=1, key=KEY)))
    users = d / "users.toml"
    if not users.exists():
        add_user(users, USER, "viewer", PASSWORD)
    lines = ['[station]', 'name = "bench"', 'data_dir = "data"', ""]
    for i in range(HOISTS):
        lines += ["[[hoist]]", f'id = "h{i}"', 'configs = ["node.json"]', 'receivers = { pithead = "loop://" }', ""]
    lines += ["[opcua]", f'endpoint = "opc.tcp://127.0.0.1:{port}/ropemon"', 'certificates = "pki"',
              'users = "users.toml"']
    p = d / "station.toml"
    p.write_text("\n".join(lines) + "\n")
    return p


def _frame_bytes(i: int) -> bytes:
    from ropemon.station.protocol import encode_frame
    t = _tension(i)
    ropes = [(t, t - 20, t + 20, 5000)] + [(5000, 4980, 5020, 5000)] * (ROPES - 1)
    return encode_frame(node=1, seq=1000 + i, time_ms=i * 100, ropes=ropes, depth_mm=100_000 + i,
                        speed_mm_s=2000, battery_mv=12_000, oil_temp_cc=2000, key=KEY)[1]


def _run(mode: str, d: Path, client_cert: tuple[str, str], seconds: float, rep: int) -> dict:
    from ropemon.station.decoder import StreamDecoder
    from ropemon.station.faces import start_faces
    from ropemon.station.hoists import Station
    from ropemon.station.link import Received
    from ropemon.station.opcua.certs import CERT_FILE
    from ropemon.station.stationfile import load_station_file

    port = free_port()
    run_dir = d / f"{mode}-{rep}"     # a fresh log each run (a reused one would refuse the frames as replays)
    run_dir.mkdir()
    for f in ("node.json", "users.toml"):
        if (d / f).exists() and not (run_dir / f).exists():
            (run_dir / f).write_bytes((d / f).read_bytes())
            os.chmod(run_dir / f, 0o600)
    sf = load_station_file(_write_station(run_dir, port))
    station = Station(sf)
    faces = start_faces(station, sf)
    face = faces[0]
    hoists = list(station.hoists)
    n_frames = int(seconds * RATE_HZ) + 1
    wire = [_frame_bytes(i) for i in range(n_frames)]
    decoded = []
    if mode == "baseline":   # decoded beforehand: the server is handed frames, no station runs
        dec = StreamDecoder({1: KEY})
        for w in wire:
            decoded.append(dec.feed(w)[0])
    ctx = mp.get_context("spawn")
    ready, out, stop = ctx.Queue(), ctx.Queue(), ctx.Event()
    url = f"opc.tcp://127.0.0.1:{port}/ropemon"
    procs = [ctx.Process(target=_client, args=(url, str(run_dir / "pki" / CERT_FILE), client_cert[0], client_cert[1],
                                                hoists, ready, stop, out), daemon=True) for _ in range(CLIENTS)]
    for p in procs:
        p.start()
    try:
        for _ in procs:
            ready.get(timeout=120)
        sent: dict[tuple[str, int], float] = {}
        period = 1.0 / RATE_HZ
        tick = 1.0 / sf.tick_hz
        # the hoists' frames spread evenly over the period, each hoist's period a little long, so
        # that over the run every hoist's frames sweep one whole period against the server's
        # publishing cycle (hoists and server clocks are not in step)
        slip = period / max(1, n_frames - 1)
        schedule = sorted((k * period / len(hoists) + i * (period + slip), k, i)
                          for i in range(n_frames) for k in range(len(hoists)))
        time.sleep(0.5)
        cpu0, t0 = time.process_time(), time.monotonic()
        next_tick = t0
        for offset, k, i in schedule:
            due = t0 + offset
            while True:
                now = time.monotonic()
                if now >= due:
                    break
                if mode == "station" and now >= next_tick:
                    station.step()
                    next_tick += tick
                    continue
                time.sleep(min(due - now, 0.005))
            h = hoists[k]
            sent[(h, _tension(i))] = time.monotonic()
            if mode == "station":
                station.hoists[h].pipeline.feed("pithead", wire[i])
            else:
                face.post(h, "frame", Received("pithead", decoded[i], time.time(), True))
        wall = time.monotonic() - t0
        cpu = time.process_time() - cpu0
        time.sleep(1.0)
        stop.set()
        results = [out.get(timeout=60) for _ in procs]
    finally:
        stop.set()
        for p in procs:
            p.join(10)
            if p.is_alive():
                p.terminate()
        for f in faces:
            f.stop()
        station.close()
    lat = [1000 * (t - sent[(h, v)]) for r in results for h, v, t in r if (h, v) in sent]
    return {"latencies_ms": lat, "cpu_percent": 100 * cpu / wall, "notifications": len(lat),
            "expected": len(sent) * CLIENTS, "dropped_by_face": face.dropped}


def _pct(xs: list[float], q: float) -> float:
    """The q-quantile, nearest rank (NaN for none)."""
    if not xs:
        return math.nan
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, math.ceil(q * len(s)) - 1))]


def measure(quick: bool = False) -> dict:
    import logging

    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    logging.getLogger("asyncua").setLevel(logging.ERROR)
    repeats, seconds = (1, 5.0) if quick else (3, 20.0)
    with tempfile.TemporaryDirectory(prefix="ropemon-bench-opcua-") as tmp:
        d = Path(tmp)
        cert, key = d / "client.der", d / "client-key.pem"
        asyncio.run(setup_self_signed_certificate(key, cert, CLIENT_URI, "localhost",
                                                  [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "bench"}))
        _write_station(d, 0)
        runs: dict[str, list[dict]] = {"station": [], "baseline": []}
        for rep in range(repeats):
            for mode in ("baseline", "station"):       # alternated: load drifts hit both
                runs[mode].append(_run(mode, d, (str(cert), str(key)), seconds, rep))
    out: dict[str, Any] = {"hoists": HOISTS, "clients": CLIENTS, "rate_hz": RATE_HZ, "repeats": repeats,
                           "seconds": seconds, "publishing_interval_ms": PUBLISH_MS,
                           "sampling_interval_ms": SAMPLING_MS, "cpus": os.cpu_count(),
                           "load_avg": os.getloadavg()}
    for mode, rs in runs.items():
        lat = [x for r in rs for x in r["latencies_ms"]]
        out[mode] = {"latency_ms_p50": _pct(lat, 0.50), "latency_ms_p95": _pct(lat, 0.95),
                     "latency_ms_p99": _pct(lat, 0.99), "latency_ms_max": max(lat) if lat else math.nan,
                     "cpu_percent": statistics.median(r["cpu_percent"] for r in rs),
                     "notifications": sum(r["notifications"] for r in rs),
                     "expected": sum(r["expected"] for r in rs),
                     "dropped_by_face": sum(r["dropped_by_face"] for r in rs)}
    for k in ("p50", "p99"):
        out[f"ratio_latency_{k}"] = out["station"][f"latency_ms_{k}"] / out["baseline"][f"latency_ms_{k}"]
    out["ratio_cpu"] = out["station"]["cpu_percent"] / out["baseline"]["cpu_percent"]
    return out


def describe(f: dict) -> str:
    load = " ".join(f"{x:.2f}" for x in f["load_avg"])
    lines = [f"OPC UA: {f['hoists']} hoists x {f['rate_hz']:g} frames/s to {f['clients']} subscribed clients "
             f"(publishing interval {f['publishing_interval_ms']:g} ms, sampling interval "
             f"{f['sampling_interval_ms']:g}), {f['repeats']} x {f['seconds']:g} s per setup "
             f"({f['cpus']} CPUs, load average {load} at the end)",
             "latency frame -> client notification, ms:",
             f"{'setup':<10} {'p50':>7} {'p95':>7} {'p99':>7} {'max':>7} {'CPU %':>7} {'notifications':>17} dropped"]
    for mode in ("baseline", "station"):
        m = f[mode]
        lines.append(f"{mode:<10} {m['latency_ms_p50']:>7.1f} {m['latency_ms_p95']:>7.1f} {m['latency_ms_p99']:>7.1f} "
                     f"{m['latency_ms_max']:>7.1f} {m['cpu_percent']:>7.1f} "
                     f"{m['notifications']:>8.0f}/{m['expected']:<8.0f} {m['dropped_by_face']:.0f}")
    lines.append(f"station / baseline: p50 x{f['ratio_latency_p50']:.2f}, p99 x{f['ratio_latency_p99']:.2f}, "
                 f"CPU x{f['ratio_cpu']:.2f}")
    return "\n".join(lines)
