"""`ropemon bench mqtt`: the Sparkplug B face under 8 hoists at 10 frames/s.

Per repeat, in the same run: the baseline station (8 hoists, alarms and logs, no face),
then the same station with the [mqtt] face (report = "frame", QoS 1, store-and-forward in
the data_dir) publishing to a local Mosquitto. The figures are the station process's CPU
(every thread) as % of one core, and the publish latency: from the station receiving a
frame (the metric's timestamp) to a subscriber in another process holding the DDATA
(outbox write, publish, broker, delivery). Medians over the repeats.
"""
from __future__ import annotations

import statistics
import time
from typing import Any

from ropemon.lab.bench.scada import FRAME_HZ, HOISTS, in_process, percentile, run_station
from ropemon.lab.localnet import Broker


def _subscriber(port: int, timeout_s: float, out: Any) -> None:
    import paho.mqtt.client as paho

    from ropemon.station.mqtt import sparkplug as sp
    lat: list[float] = []
    done = []
    seq_aliases: set[int] = set()     # the frame_seq metrics' aliases (DDATA names by alias only)
    c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="bench-sub")

    def on_message(client, userdata, msg):
        now = time.time() * 1000
        kind = msg.topic.split("/")[2]
        if kind == "NDEATH":
            done.append(1)
        elif kind == "DBIRTH":
            seq_aliases.update(m.alias for m in sp.decode(msg.payload).metrics if m.name.endswith("/frame_seq"))
        elif kind == "DDATA":
            p = sp.decode(msg.payload)
            for m in p.metrics:
                if m.alias in seq_aliases or m.name.endswith("/frame_seq"):
                    lat.append(now - m.timestamp)
                    break

    def on_connect(client, *a):
        client.subscribe("spBv1.0/#", qos=1)
        rebirth = sp.payload(None)            # joined after the births: ask for them (the aliases)
        sp.add_metric(rebirth, "Node Control/Rebirth", sp.BOOLEAN, True, rebirth.timestamp)
        client.publish(sp.topic("bench", "NCMD", "station"), rebirth.SerializeToString(), qos=1)
        out.put("ready")

    c.on_connect = on_connect
    c.on_message = on_message
    c.connect("127.0.0.1", port)
    c.loop_start()
    end = time.monotonic() + timeout_s
    while not done and time.monotonic() < end:
        time.sleep(0.05)
    c.loop_stop()
    out.put(lat)


def measure(quick: bool = False) -> dict:
    seconds, repeats = (4.0, 1) if quick else (15.0, 3)
    broker = Broker()
    runs: list[dict[str, Any]] = []
    try:
        for _ in range(repeats):
            base = run_station("", seconds)
            sub: dict[str, Any] = {}

            def ready(faces: list) -> None:
                sub["p"], sub["q"] = in_process(_subscriber, broker.port, seconds + 30)
                assert sub["q"].get(timeout=30) == "ready"

            table = (f'[mqtt]\nport = {broker.port}\ngroup_id = "bench"\nedge_node_id = "station"\n'
                     'report = "frame"\nqos = 1\n')
            face = run_station(table, seconds, ready)
            lat = sub["q"].get(timeout=60)
            sub["p"].join(10)
            runs.append({"cpu_base": base["cpu_pct"], "cpu_mqtt": face["cpu_pct"], "frames": face["frames"],
                         "received": len(lat), "p50_ms": percentile(lat, 0.5), "p99_ms": percentile(lat, 0.99),
                         "max_ms": max(lat) if lat else float("nan")})
    finally:
        broker.close()
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    return {"hoists": HOISTS, "frame_hz": FRAME_HZ, "seconds": seconds, "repeats": repeats,
            "median": med, "runs": runs}


def describe(f: dict) -> str:
    m = f["median"]
    return "\n".join([
        f"ropemon bench mqtt: {f['hoists']} hoists x {f['frame_hz']:.0f} frames/s, {f['seconds']:.0f} s, "
        f"median of {f['repeats']} repeat(s)",
        f"  station CPU, baseline (alarms, logs, no face):   {m['cpu_base']:6.1f} % of one core",
        f"  station CPU, with the MQTT face (frame, QoS 1):  {m['cpu_mqtt']:6.1f} % of one core "
        f"(+{m['cpu_mqtt'] - m['cpu_base']:.1f})",
        f"  DDATA received / frames fed:                      {m['received']:.0f} / {m['frames']:.0f}",
        f"  publish latency (frame received -> subscriber):   p50 {m['p50_ms']:.1f} ms, "
        f"p99 {m['p99_ms']:.1f} ms, max {m['max_ms']:.1f} ms",
    ])
