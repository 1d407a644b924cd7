"""`ropemon bench fleet`: 200 hoists' Sparkplug B through one Mosquitto into the fleet consumer.

Setup (all on this machine, one Mosquitto from lab/localnet, a new one per run):

- publishers: 10 edge nodes (stations) x 20 hoists (devices), one node of 4 ropes each, 10
  frames/s per hoist = 2,000 frames/s, in 2 processes of 5 edge nodes. Each edge node is
  the product's MQTT face (`station.mqtt.MqttFace`: outbox on disk in its own data_dir,
  QoS 1, report = "frame") with one `SparkplugValues` listener per hoist, handed each frame
  as the station hands it (`on_frame`, a decoded frame; no radio decoding, alarms or logs:
  those are `ropemon bench mqtt`'s). Hoists are spread evenly over the 0.1 s period.
- the consumer: the product's `ropemon fleet` (`station.mqtt.fleet.Fleet`, persistent
  session, SQLite historian on disk) in a process of its own.
- the baseline, measured in the same run: the same processes, broker and pacing, but each
  edge node a bare paho client publishing payloads of a DDATA's size (QoS 1, no outbox, no
  Sparkplug), consumed by the same `Fleet` whose message decoding is replaced by a struct
  unpack into the same 4 rows; the historian, the commits and the acknowledgements are the
  product's.

Figures per run: frames/s reaching the historian (committed) over the steady window, the
latency from the station handing the frame over (the metric's timestamp) to the commit of
its row (p50/p99/max), frames lost (every (edge node, hoist, frame_seq, rope 1-4) fed is
looked up in the historian), each process's CPU (% of one core) and the load average.
The outage run (not in --quick) kills Mosquitto (SIGKILL) at 20 s, restarts it 30 s later
on the same port with the same persistence, and measures the catch-up: from the restart
until every frame handed over before the restart is committed and the latency stays under
LIVE_MS.
"""
from __future__ import annotations

import array
import os
import statistics
import struct
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from ropemon.lab.bench.scada import in_process, percentile
from ropemon.lab.localnet import Broker

GROUP = "bench"
FRAME_HZ = 10.0
EDGES, HOISTS_PER_EDGE, PROCS = 10, 20, 2
OUTAGE_AT_S, OUTAGE_S = 20.0, 30.0
LIVE_MS = 1000.0           # "live again" after the outage: every frame's latency under this
SLOTS = 20                 # feeding ticks per frame period (the hoists are spread over them)


def _edge_ids(edges: int) -> list[str]:
    return [f"edge{e:02d}" for e in range(edges)]


def _hoist_ids(per_edge: int) -> list[str]:
    return [f"h{h:02d}" for h in range(per_edge)]


def _cpu() -> float:
    t = os.times()
    return t.user + t.system


def _proc_cpu(pid: int) -> float:
    """A process's user + system CPU seconds (Linux /proc)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


# -- publishers ------------------------------------------------------------------------------

def _template() -> Any:
    from ropemon.station.protocol import decode_raw, encode_frame
    raw = encode_frame(node=1, seq=1, time_ms=100, ropes=[(5000 + 10 * r, 4950, 5050, 8000) for r in range(4)],
                       depth_mm=12_000, speed_mm_s=1000, battery_mv=12_000)[0]
    return decode_raw(raw)


def ddata_size() -> int:
    """The size of one hoist's DDATA as the product sends it (the baseline's payload size)."""
    from ropemon.station.mqtt import sparkplug as sp
    from ropemon.station.scadavalues import node_values
    values = sp.frame_values(node_values(_template(), time.time(), 0.0))
    values.update({"alarms/present": 0, "alarms/unacknowledged": 0, "vouched": True})
    devices = {h: sp.hoist_metrics([1]) for h in _hoist_ids(HOISTS_PER_EDGE)}
    types = {n: t for n, t, _ in devices[_hoist_ids(HOISTS_PER_EDGE)[-1]]}
    alias = sp.aliases(devices)[_hoist_ids(HOISTS_PER_EDGE)[-1]]     # by alias, as the face sends DDATA
    p = sp.payload(1)
    for name, value in values.items():
        sp.add_metric(p, None, types[name], value, sp.now_ms(), alias=alias[name])
    return len(p.SerializeToString())


def _publisher(mode: str, port: int, edges: list[str], per_edge: int, data_dir: str, ctl: Any, out: Any) -> None:
    """One process of edge nodes: the product's face ("product") or bare paho ("raw")."""
    import dataclasses

    import paho.mqtt.client as paho

    from ropemon.station.link import Received
    hoists = _hoist_ids(per_edge)
    feeders: list[Any] = []          # per hoist: a callable feed(seq)
    faces: list[Any] = []
    clients: list[Any] = []
    acked = [0]
    if mode == "product":
        from ropemon.station.mqtt import MqttFace, SparkplugValues, parse_table
        tmpl = _template()
        for e in edges:
            d = Path(data_dir) / e
            station = SimpleNamespace(config=SimpleNamespace(data_dir=d),
                                       hoists={h: SimpleNamespace(id=h, keys={1: b""}) for h in hoists})
            table = {"port": port, "group_id": GROUP, "edge_node_id": e, "report": "frame", "qos": 1}
            face = MqttFace(station, parse_table(table, d))
            face.start()
            faces.append(face)
            for h in hoists:
                listener = SparkplugValues(face, h, [1])

                def feed(seq: int, li: Any = listener) -> None:
                    now = time.monotonic()
                    f = dataclasses.replace(tmpl, seq=seq, time_ms=seq * 100)
                    li.on_frame(Received("pithead", f, now, True), now)
                feeders.append(feed)
    else:
        pad = max(0, ddata_size() - 16)
        for i, e in enumerate(edges):
            c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=f"raw-{e}", protocol=paho.MQTTv311)
            c.max_inflight_messages_set(200)

            def on_publish(client, userdata, mid, reason, props) -> None:
                acked[0] += 1
            c.on_publish = on_publish
            c.connect("127.0.0.1", port, keepalive=10)
            c.loop_start()
            clients.append(c)
            for h in hoists:
                topic = f"spBv1.0/{GROUP}/DDATA/{e}/{h}"

                def feed(seq: int, c: Any = c, topic: str = topic) -> None:
                    c.publish(topic, struct.pack("<QQ", int(time.time() * 1000), seq) + b"\0" * pad, qos=1)
                feeders.append(feed)
    end = time.monotonic() + 20
    while time.monotonic() < end and not all(x.connected if faces else x.is_connected() for x in faces or clients):
        time.sleep(0.05)
    out.put("ready")
    start_at, seconds, drain_s = ctl.get()
    time.sleep(max(0.0, start_at - time.time()))
    c0, t0 = _cpu(), time.monotonic()
    slots = [feeders[k::SLOTS] for k in range(SLOTS)]
    ticks = int(round(seconds * FRAME_HZ * SLOTS))
    dt = 1.0 / (FRAME_HZ * SLOTS)
    late = 0.0
    for k in range(ticks):
        due = t0 + k * dt
        wait = due - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        else:
            late = max(late, -wait)
        seq = k // SLOTS + 1
        for feed in slots[k % SLOTS]:
            feed(seq)
    feed_s = time.monotonic() - t0
    fed = ticks // SLOTS
    c1 = _cpu()
    end = time.monotonic() + drain_s
    if faces:
        while time.monotonic() < end and not all(f.outbox.rows == 0 and not f._inflight for f in faces):
            time.sleep(0.05)
        left = sum(f.outbox.rows for f in faces)
    else:
        while time.monotonic() < end and acked[0] < fed * len(feeders):
            time.sleep(0.05)
        left = fed * len(feeders) - acked[0]
    drained_s = time.monotonic() - t0
    c2 = _cpu()
    for f in faces:
        f.stop()
    for c in clients:
        c.disconnect()
        c.loop_stop()
    out.put({"fed": fed, "hoists": len(feeders), "feed_s": feed_s, "late_s": late, "cpu_feed": c1 - c0,
             "cpu_all": c2 - c0, "drained_s": drained_s, "left": left,
             "sessions": sum(f.sessions for f in faces), "dropped": sum(f.outbox.dropped for f in faces)})


# -- the consumer ----------------------------------------------------------------------------

def _consumer(mode: str, port: int, db: str, ctl: Any, out: Any) -> None:
    from ropemon.station.mqtt.fleet import Fleet, Historian

    class TimedHistorian(Historian):
        """The product's historian; notes each committed frame's (commit time, frame time)."""

        def __init__(self, path: str) -> None:
            super().__init__(path)
            self.commit_ms = array.array("d")
            self.frame_ms = array.array("d")

        def write(self, rows: list[tuple], *held: Any) -> None:
            super().write(rows, *held)
            now = time.time() * 1000
            for r in rows:
                if r[4] == 1:
                    self.commit_ms.append(now)
                    self.frame_ms.append(r[5])

    class RawFleet(Fleet):
        """The baseline's consumer: the same Fleet, a struct unpack instead of Sparkplug."""

        def rows_of(self, topic: str, payload: bytes) -> list[tuple]:
            _, group, kind, edge, device = topic.split("/")
            ts, seq = struct.unpack_from("<QQ", payload)
            return [(group, edge, device, 1, r, ts, 50.0, seq, False) for r in range(1, 5)]

    class Timed(Fleet if mode == "product" else RawFleet):  # type: ignore[misc,valid-type]
        """Notes when each frame reached the consumer (paho's on_message, in order)."""

        def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
            received.append(time.time() * 1000)
            super()._on_message(client, userdata, msg)

        def rows_of(self, topic: str, payload: bytes) -> list[tuple]:
            at = received.popleft()
            rows = super().rows_of(topic, payload)
            if rows:
                arrival_ms.append(at - rows[0][5])
            return rows

    from collections import deque
    received: deque[float] = deque()

    arrival_ms = array.array("d")
    hist = TimedHistorian(db)
    fleet = Timed(hist, port=port, group=GROUP, client_id=f"bench-{mode}")
    fleet.start()
    fleet.connected.wait(20)
    time.sleep(0.3)
    out.put("ready")
    c0, t0 = _cpu(), time.monotonic()
    expected, deadline = ctl.get()
    want = 4 * sum(expected.values())
    while time.time() < deadline:
        with fleet.lock:
            if fleet.stats["rows"] >= want:
                break
        time.sleep(0.05)
    c1, t1 = _cpu(), time.monotonic()
    fleet.stop()
    lost = 0
    got = {(e, d): (n, lo, hi) for e, d, n, lo, hi in hist.conn.execute(
        "SELECT edge_node, device, COUNT(*), MIN(frame_seq), MAX(frame_seq) FROM tension "
        "WHERE node = 1 AND rope BETWEEN 1 AND 4 GROUP BY edge_node, device")}
    for key, frames in expected.items():
        n, lo, hi = got.get(key, (0, 1, 0))
        inside = n if (lo >= 1 and hi <= frames) else hist.conn.execute(
            "SELECT COUNT(*) FROM tension WHERE edge_node = ? AND device = ? AND node = 1 AND rope BETWEEN 1 AND 4 "
            "AND frame_seq BETWEEN 1 AND ?", (*key, frames)).fetchone()[0]
        lost += 4 * frames - inside
    historical = hist.conn.execute("SELECT COUNT(*) FROM tension WHERE historical").fetchone()[0]
    out.put({"lost_rows": lost, "arrival_ms": arrival_ms.tobytes(), "commit_ms": hist.commit_ms.tobytes(), "frame_ms": hist.frame_ms.tobytes(),
             "cpu_pct": 100 * (c1 - c0) / (t1 - t0), "stats": dict(fleet.stats), "historical_rows": historical})
    hist.close()


# -- one run ---------------------------------------------------------------------------------

def run(mode: str = "product", edges: int = EDGES, per_edge: int = HOISTS_PER_EDGE, procs: int = PROCS,
        seconds: float = 60.0, warmup_s: float = 5.0, outage: tuple[float, float] | None = None,
        drain_s: float = 300.0) -> dict[str, Any]:
    """One run: `mode` "product" or "raw" (the baseline). `outage`: (at_s, for_s) after the start."""
    names = _edge_ids(edges)
    with tempfile.TemporaryDirectory(prefix="ropemon-bench-fleet-") as d:
        broker = Broker(Path(d))
        procs_ = []
        try:
            cons, cq_in, cq = _spawn(_consumer, mode, broker.port, str(Path(d) / "fleet.db"))
            assert cq.get(timeout=60) == "ready", "the consumer did not start"
            shares = [names[k::procs] for k in range(procs) if names[k::procs]]
            pubs = [_spawn(_publisher, mode, broker.port, share, per_edge, d) for share in shares]
            procs_ = [cons] + [p for p, _, _ in pubs]
            for _, _, q in pubs:
                assert q.get(timeout=60) == "ready", "a publisher did not start"
            start_at = time.time() + 0.5
            for _, qin, _ in pubs:
                qin.put((start_at, seconds, drain_s))
            time.sleep(max(0.0, start_at - time.time()))
            b0, t0 = _proc_cpu(broker.proc.pid), time.time()
            restart_at = None
            broker_cpu = 0.0
            if outage is not None:
                time.sleep(max(0.0, t0 + outage[0] - time.time()))
                broker_cpu += _proc_cpu(broker.proc.pid) - b0
                broker.kill()
                time.sleep(outage[1])
                broker.start()
                restart_at = time.time()
                b0 = _proc_cpu(broker.proc.pid)
            time.sleep(max(0.0, t0 + seconds - time.time()))
            load = os.getloadavg()
            broker_cpu += _proc_cpu(broker.proc.pid) - b0
            broker_wall = time.time() - t0 - (outage[1] if outage else 0.0)
            results = [q.get(timeout=seconds + drain_s + 120) for _, _, q in pubs]
            expected = {(e, h): r["fed"] for r, share in zip(results, shares) for e in share
                        for h in _hoist_ids(per_edge)}
            cq_in.put((expected, time.time() + 120))
            c = cq.get(timeout=300)
            for p in procs_:
                p.join(30)
        finally:
            for p in procs_:
                if p.is_alive():
                    p.kill()
            broker.close()
    commit = array.array("d")
    commit.frombytes(c["commit_ms"])
    frame = array.array("d")
    frame.frombytes(c["frame_ms"])
    t0_ms, feed_end_ms = t0 * 1000, (t0 + seconds) * 1000
    lat = [cm - fm for cm, fm in zip(commit, frame)]
    arrival = array.array("d")
    arrival.frombytes(c["arrival_ms"])
    k0 = int(len(arrival) * warmup_s / seconds)
    arrival = arrival[k0:int(len(arrival) * min(1.0, (seconds - 0.5) / seconds))] if outage is None else arrival
    steady = [x for x, cm, fm in zip(lat, commit, frame) if fm >= t0_ms + warmup_s * 1000 and fm < feed_end_ms]
    window_s = seconds - warmup_s
    in_window = sum(1 for cm in commit if t0_ms + warmup_s * 1000 <= cm < feed_end_ms)
    frames = sum(r["fed"] * r["hoists"] for r in results)
    feed_s = max(r["feed_s"] for r in results)
    out: dict[str, Any] = {
        "mode": mode, "edges": edges, "hoists": edges * per_edge, "procs": len(results), "seconds": seconds,
        "offered_fps": frames / feed_s, "committed_fps": in_window / window_s,
        "frames": frames, "lost": c["lost_rows"] // 4 if c["lost_rows"] % 4 == 0 else c["lost_rows"] / 4,
        "lost_rows": c["lost_rows"],
        "arrive_p50_ms": percentile(list(arrival), 0.5), "arrive_p99_ms": percentile(list(arrival), 0.99),
        "p50_ms": percentile(steady, 0.5), "p99_ms": percentile(steady, 0.99),
        "max_ms": max(steady) if steady else float("nan"),
        "drain_after_feed_s": max(0.0, (max(commit) - feed_end_ms) / 1000) if commit else float("nan"),
        "rows_per_commit": 4 * len(commit) / max(1, c["stats"]["commits"]),
        "feeder_late_max_ms": 1000 * max(r["late_s"] for r in results),
        "cpu_publishers_pct": 100 * sum(r["cpu_feed"] for r in results) / feed_s,
        "cpu_consumer_pct": c["cpu_pct"],
        "cpu_broker_pct": 100 * broker_cpu / broker_wall,
        "load_avg": load, "consumer": c["stats"], "historical_rows": c["historical_rows"],
        "outbox_left": sum(r["left"] for r in results), "outbox_dropped": sum(r["dropped"] for r in results),
    }
    if restart_at is not None:
        r_ms = restart_at * 1000
        backlog = [cm for cm, fm in zip(commit, frame) if fm < r_ms]
        drained = (max(backlog) - r_ms) / 1000 if backlog else 0.0
        late_after = [cm for cm, x in zip(commit, lat) if cm >= r_ms and x >= LIVE_MS]
        live = (max(late_after) - r_ms) / 1000 if late_after else 0.0
        out.update({"outage_s": outage[1], "backlog_frames": sum(1 for fm in frame if t0_ms + outage[0] * 1000 <= fm < r_ms),
                    "backlog_drained_s": drained, "live_again_s": live, "catch_up_s": max(drained, live),
                    "sessions": sum(r["sessions"] for r in results)})
    return out


def _spawn(target: Any, *args: Any) -> tuple[Any, Any, Any]:
    """target(*args, ctl, out) in a fresh process; returns (process, ctl queue, out queue)."""
    import multiprocessing as mp
    ctx = mp.get_context("spawn")
    ctl, out = ctx.Queue(), ctx.Queue()
    p = ctx.Process(target=target, args=(*args, ctl, out), daemon=True)
    p.start()
    return p, ctl, out


# -- the bench -------------------------------------------------------------------------------

KEYS = ("committed_fps", "offered_fps", "arrive_p50_ms", "arrive_p99_ms", "p50_ms", "p99_ms", "max_ms", "lost", "drain_after_feed_s",
        "cpu_publishers_pct", "cpu_consumer_pct", "cpu_broker_pct")


def measure(quick: bool = False) -> dict:
    if quick:
        kw: dict[str, Any] = {"edges": 2, "per_edge": 10, "procs": 1, "seconds": 6.0, "warmup_s": 2.0}
        repeats = 1
    else:
        kw = {"edges": EDGES, "per_edge": HOISTS_PER_EDGE, "procs": PROCS, "seconds": 60.0, "warmup_s": 5.0}
        repeats = 3
    runs: dict[str, list[dict]] = {"raw": [], "product": []}
    for _ in range(repeats):
        for mode in ("raw", "product"):
            runs[mode].append(run(mode, **kw))
    outage = None
    if not quick:
        outage = run("product", **{**kw, "seconds": OUTAGE_AT_S + OUTAGE_S + 40.0}, outage=(OUTAGE_AT_S, OUTAGE_S))
    med = {mode: {k: statistics.median(r[k] for r in rs) for k in KEYS} for mode, rs in runs.items()}
    return {**kw, "repeats": repeats, "frame_hz": FRAME_HZ, "ddata_bytes": ddata_size(), "median": med,
            "runs": runs, "outage": outage}


def describe(f: dict) -> str:
    m = f["median"]
    hoists = f["edges"] * f["per_edge"]
    lines = [
        f"ropemon bench fleet: {f['edges']} edge nodes x {f['per_edge']} hoists = {hoists} hoists x "
        f"{f['frame_hz']:.0f} frames/s = {hoists * f['frame_hz']:.0f} frames/s offered, {f['procs']} publisher "
        f"process(es), {f['seconds']:.0f} s per run ({f['warmup_s']:.0f} s warm-up), median of {f['repeats']} "
        f"repeat(s); DDATA {f['ddata_bytes']} bytes",
        f"  {'':42s} {'baseline (raw paho)':>20s} {'product':>12s}",
    ]
    rows = [("frames/s offered", "offered_fps", "{:.0f}"), ("frames/s committed (steady window)", "committed_fps", "{:.0f}"),
            ("latency p50, ms (frame -> consumer)", "arrive_p50_ms", "{:.1f}"),
            ("latency p99, ms (frame -> consumer)", "arrive_p99_ms", "{:.1f}"),
            ("latency p50, ms (frame -> row committed)", "p50_ms", "{:.1f}"),
            ("latency p99, ms (frame -> row committed)", "p99_ms", "{:.1f}"),
            ("latency max, ms (frame -> row committed)", "max_ms", "{:.1f}"), ("frames lost", "lost", "{:.0f}"),
            ("drain after the feed ends, s", "drain_after_feed_s", "{:.2f}"),
            ("CPU publishers, % of one core", "cpu_publishers_pct", "{:.0f}"),
            ("CPU consumer, % of one core", "cpu_consumer_pct", "{:.0f}"),
            ("CPU mosquitto, % of one core", "cpu_broker_pct", "{:.0f}")]
    for label, k, fmt in rows:
        lines.append(f"  {label:42s} {fmt.format(m['raw'][k]):>20s} {fmt.format(m['product'][k]):>12s}")
    loads = [r["load_avg"][0] for rs in f["runs"].values() for r in rs]
    lines.append(f"  load average (1 min) at the runs' ends: {min(loads):.2f}-{max(loads):.2f} on {os.cpu_count()} cores")
    o = f.get("outage")
    if o:
        lines += [
            f"  outage run ({o['seconds']:.0f} s, product): Mosquitto SIGKILLed at {OUTAGE_AT_S:.0f} s, restarted "
            f"{o['outage_s']:.0f} s later on the same port and persistence",
            f"    frames {o['frames']}, lost {o['lost']}, handed over during the outage {o['backlog_frames']}, "
            f"historical rows {o['historical_rows']}",
            f"    backlog committed {o['backlog_drained_s']:.1f} s after the restart; latency under "
            f"{LIVE_MS:.0f} ms for good {o['live_again_s']:.1f} s after it: catch-up {o['catch_up_s']:.1f} s",
            f"    committed {o['committed_fps']:.0f} frames/s over the run, drain after the feed "
            f"{o['drain_after_feed_s']:.1f} s, load {o['load_avg'][0]:.2f}",
        ]
    return "\n".join(lines)
