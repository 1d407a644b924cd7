"""`ropemon demo`: the whole chain on the simulated hoist, as `make demo` runs it.

simulator (paper-field-trip) -> sensor stream -> node firmware in the real
`micropython` unix port with its sim HAL -> radio model (loss and bit errors
growing with depth, pithead and mid-shaft receivers) -> two virtual serial
ports (pty pairs) -> the host reads them with pyserial -> decode, merge,
alarms, SQLite log, live monitor -> summary against the simulator's truth.

The wind is played faster than real time; the host runs on a demo clock that
advances `speed` seconds per wall second, so alarm durations and trip
detection see the node's time scale.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ropemon.lab import radio
from ropemon.firmware import FIRMWARE_DIR
from ropemon.station.alarms import AlarmSettings
from ropemon.station import assembly
from ropemon.station.assembly import HoistSpec, run_loop
from ropemon.station.link import Received
from ropemon.station.pipeline import AlarmListener, Listener, HoistPipeline
from ropemon.station.protocol import DAN_TO_N, Frame, FrameError, L, decode_raw, decode_wire, load_node_keys
from ropemon.station.report import REST_AVG_S, SETTLE_S
from ropemon.station.nodefigures import NodeFigures

DEFAULT_OUT = "out/demo"
DEMO_HOIST = "demo"
DEMO_OPERATOR = "demo"


class DemoClock:
    """Wall time sped up: `speed` demo seconds per real second, starting at `start_s`."""

    def __init__(self, speed: float, start_s: float | None = None) -> None:
        self.speed = speed
        self.m0 = time.monotonic()
        self.start_s = time.time() if start_s is None else start_s

    def __call__(self) -> float:
        return self.start_s + (time.monotonic() - self.m0) * self.speed


@dataclass
class Sent:
    """What the node put on the radio, frame by frame."""

    wires: list[bytes]
    frames: list[Frame]


def read_frames_bin(path: Path, keys: dict[int, bytes] | None = None) -> Sent:
    """Split the replay output into wire frames; every one must decode (it left the node intact)."""
    data = path.read_bytes()
    wires, frames = [], []
    for body in data.split(b"\x00")[:-1]:
        if not body:
            continue
        frames.append(decode_raw(decode_wire(body), keys))
        wires.append(b"\x00" + body + b"\x00")   # as the node sends it: delimited on both sides
    return Sent(wires, frames)


def load_truth(sim_dir: Path) -> dict[str, np.ndarray]:
    with np.load(sim_dir / "truth.npz") as z:
        return {k: z[k] for k in z.files}


def truth_time_s(truth: dict[str, np.ndarray], sample_hz: float) -> np.ndarray:
    for k in ("t_s", "time_s", "t"):
        if k in truth:
            return np.asarray(truth[k], float)
    n = len(truth["tension_N"])
    return np.arange(n) / sample_hz


def depth_at(truth: dict[str, np.ndarray], t_truth: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """True cage depth at node times t_s (the radio link depends on where the cage really is)."""
    return np.interp(t_s, t_truth, np.asarray(truth["cage_depth_m"], float))


# -- comparison with the truth ---------------------------------------------------------


def window_truth(tension_n: np.ndarray, t_truth: np.ndarray, frame_t_s: np.ndarray,
                 window_s: float) -> np.ndarray:
    """True tension averaged over each frame's window (window_s before the frame's time)."""
    c = np.vstack([np.zeros((1, tension_n.shape[1])), np.cumsum(tension_n, axis=0)])
    # The node stamps a frame with the time just after its window's last sample.
    lo = np.searchsorted(t_truth, frame_t_s - window_s - 1e-9, side="left")
    hi = np.searchsorted(t_truth, frame_t_s - 1e-9, side="left")
    hi = np.maximum(hi, lo + 1).clip(max=len(tension_n))
    lo = lo.clip(max=len(tension_n) - 1)
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


def accuracy(frames: list[Frame], truth: dict[str, np.ndarray], t_truth: np.ndarray, area_m2: list[float],
             rated_rope_n: float, window_s: float) -> dict:
    """Per-rope and total-load error of raw and compensated tension against the truth,
    frames aligned to the truth by node time; % of rated rope tension (total: % of N x rated)."""
    from ropemon.lab.metrics import error_figures

    fs = [f for f in frames if f.ropes and not f.status & L.ST_CONFIG_FAULT]
    # A rope whose sensor failed for the whole window carries no tension: such
    # frames are counted, not compared.
    failed = [f for f in fs if any(r.mean_dan == L.TENSION_ABSENT or r.raw_kpa == L.RAW_KPA_ABSENT
                                   for r in f.ropes)]
    fs = [f for f in fs if f not in failed] if failed else fs
    if not fs:
        return {"frames": 0, "frames_with_failed_sensor": len(failed)}
    t = np.array([f.time_ms / 1000 for f in fs])
    comp = np.array([[r.mean_dan * DAN_TO_N for r in f.ropes] for f in fs], float)
    raw = np.array([[r.raw_kpa * 1000.0 * area_m2[i] for i, r in enumerate(f.ropes)] for f in fs], float)
    true = window_truth(np.asarray(truth["tension_N"], float), t_truth, t, window_s)
    keep = np.ones(len(t), bool)
    out = {"frames": len(t), "frames_with_failed_sensor": len(failed), "window_s": window_s,
           "compensated": error_figures(comp, true, rated_rope_n, keep),
           "raw": error_figures(raw, true, rated_rope_n, keep)}
    speed = np.interp(t, t_truth, np.asarray(truth["cage_speed_m_s"], float))
    depth = np.interp(t, t_truth, np.asarray(truth["cage_depth_m"], float))
    # The paper's figure: the pithead rest just after the wind (as report.py takes
    # it: REST_AVG_S after the cage settled), before any unloading.
    rest_top = np.zeros(len(t), bool)
    moved = np.flatnonzero(np.abs(speed) >= 0.01)
    if moved.size and depth[moved[-1]] < 0.5 * max(float(np.max(truth["cage_depth_m"])), 1.0):
        t_arrive = t[moved[-1]]
        rest_top = (t >= t_arrive + SETTLE_S) & (t < t_arrive + SETTLE_S + REST_AVG_S) & (np.abs(speed) < 0.01)
    if rest_top.any():
        ts = true[rest_top].sum(axis=1).mean()
        out["pithead_rest"] = {
            "frames": int(rest_top.sum()),
            "true_total_kN": ts / 1000,
            "raw_total_kN": raw[rest_top].sum(axis=1).mean() / 1000,
            "compensated_total_kN": comp[rest_top].sum(axis=1).mean() / 1000,
        }
    out["_series"] = (t, comp, raw, true)
    return out


def plot_demo(acc: dict, out: Path) -> Path:
    """Total load over the wind (truth, compensated, raw) and each rope's compensated error."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, comp, raw, true = acc["_series"]
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    a1.plot(t, true.sum(axis=1) / 1000, "k", lw=1.5, label="truth (simulator)")
    a1.plot(t, comp.sum(axis=1) / 1000, lw=1.0, label="compensated (node)")
    a1.plot(t, raw.sum(axis=1) / 1000, lw=1.0, ls="--", label="raw p x A")
    a1.set_ylabel("total load, kN")
    a1.legend(fontsize=8)
    a1.grid(True, alpha=0.3)
    a1.set_title("ropemon demo: paper field trip, frames received by the host")
    for i in range(comp.shape[1]):
        a2.plot(t, (comp[:, i] - true[:, i]) / 1000, lw=0.8, label=f"rope {i + 1}")
    a2.set_ylabel("compensated - true, kN")
    a2.set_xlabel("node time, s")
    a2.grid(True, alpha=0.3)
    a2.legend(fontsize=8, ncol=4)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


# -- the chain ---------------------------------------------------------------------------


class FrameKeeper(Listener):
    """Keeps every new frame, to compare with the truth."""

    name = "demo frames"

    def __init__(self) -> None:
        self.frames: list[Frame] = []
        self.last_rx_s: float | None = None   # the station's time of the last new frame

    def on_frame(self, item: Received, now_s: float) -> None:
        self.frames.append(item.frame)
        self.last_rx_s = now_s


@dataclass
class DemoHost:
    """The station as the demo runs it, and the listeners it reads back."""

    pipeline: HoistPipeline
    alarms: AlarmListener
    kept: FrameKeeper
    store: Any = None
    view: Any = None   # MonitorView: the live screen


def demo_host(keys: dict[int, bytes] | None, settings: AlarmSettings | None, clock: Callable[[], float],
              store: Any = None, view: Any = None, figures: Any = None) -> DemoHost:
    """The hoist room's station (`assembly.build_hoist`: alarms, the log, a frame keeper, the
    view), everything on the demo's clock: alarm timing, events, rx times."""
    kept = FrameKeeper()
    spec = HoistSpec(DEMO_HOIST, figures or NodeFigures(), keys or {}, settings)
    views = [kept] + ([view] if view is not None else [])
    hoist = assembly.build_hoist(spec, clock, wall=clock, store=store, views=views)
    return DemoHost(hoist.pipeline, hoist.alarms, kept, store, view)


def simulate(scenario: str, sim_dir: Path, seed: int) -> None:
    """`ropemon simulate` in a child process (the plant owns its CLI and progress output)."""
    cmd = [sys.executable, "-m", "ropemon.cli", "simulate", scenario, "--out", str(sim_dir), "--seed", str(seed)]
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"simulate {scenario} failed (exit {r.returncode}):\n{r.stdout[-2000:]}")


def start_players(ports: dict, deliveries: dict[str, list[radio.Delivery]], speed: float, station: HoistPipeline,
                  who: str, players: list, drain_s: float = 1.0) -> Callable[[], bool]:
    """Once every receiver port of `station` is open (pyserial flushes the input when it opens a
    port: writing sooner would throw the first frames away), start a `Player` per pty into
    `players`, all measured from the same first time so that the lines stay in step. Returns
    done(): the players ended and the station read every byte, or `drain_s` passed since."""
    from ropemon.lab.vserial import Player

    readers = list(station.hub.receivers.values())
    deadline = time.monotonic() + 10.0
    while not all(r.connected for r in readers):
        if time.monotonic() > deadline:
            raise RuntimeError(f"the {who} could not open the virtual ports: "
                               + "; ".join(r.last_error or r.name for r in readers if not r.connected))
        time.sleep(0.01)
    first = min((d[0].t_s for d in deliveries.values() if d), default=0.0)
    t0 = time.monotonic()
    for name, vp in ports.items():
        p = Player(vp, [(first, b"")] + [(d.t_s, d.data) for d in deliveries[name]], speed, t0=t0)
        p.start()
        players.append(p)
    total = sum(len(d.data) for v in deliveries.values() for d in v)
    quiet_since: list[float] = []   # when the players ended with bytes still unread

    def done() -> bool:
        if any(p.is_alive() for p in players):
            return False
        if sum(r.bytes_read for r in readers) >= total:
            return True
        if not quiet_since:
            quiet_since.append(time.monotonic())
        return time.monotonic() - quiet_since[0] > drain_s
    return done


def stop_players(players: list) -> dict[str, int]:
    """Stop the players; bytes written per receiver (RuntimeError if one failed)."""
    for p in players:
        p.stop()
        p.join(2.0)
        if p.error is not None:
            raise RuntimeError(f"playing receiver {p.port.name} failed: {p.error}")
    return {p.port.name: p.written for p in players}


def play_to_host(deliveries: dict[str, list[radio.Delivery]], host: DemoHost, speed: float, clock: DemoClock,
                 view_console=None, refresh_hz: float = 4.0, drain_s: float = 1.0) -> dict[str, int]:
    """Write each receiver's deliveries into its own pty, paced; the host reads the ptys
    with pyserial. Returns bytes written per receiver."""
    from ropemon.lab.vserial import VirtualPort

    ports = {name: VirtualPort(name) for name in deliveries}
    players: list = []
    try:
        session = host.pipeline
        for name, vp in ports.items():
            session.add_port(vp.port, name).start()
        done = start_players(ports, deliveries, speed, session, "host", players, drain_s)
        if view_console is not None:
            from ropemon.station.monitor import live_loop
            live_loop(session, host.view, view_console, refresh_hz, done)
            if not done():          # the operator pressed q: skip to the summary
                for p in players:
                    p.stop()
            session.tick()
            view_console.print(host.view.render(session.clock()))  # the last screen stays visible
        run_loop([session], 0.05, done)
        written = stop_players(players)
        session.close()
        return written
    finally:
        for p in players:
            p.stop()
        host.pipeline.hub.stop()
        for vp in ports.values():
            vp.close()


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--headless", action="store_true", help="no live monitor: print the summary only")
    p.add_argument("--scenario", default="paper-field-trip", help="simulator scenario (default paper-field-trip)")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"working directory (default {DEFAULT_OUT})")
    p.add_argument("--speed", type=float, default=None,
                   help="playback speed-up over real time (default: 4 live, 20 headless)")
    p.add_argument("--seed", type=int, default=1, help="seed of the simulator noise and the radio")
    p.add_argument("--interpreter", choices=("micropython", "cpython"), default="micropython",
                   help="where the node firmware runs (default: the real micropython unix port)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument("--serve", action="store_true",
                   help="play the wind in real time through a station with its web face (the station file's "
                        "faces with --station; else one written to OUT/station.toml) and keep serving after "
                        "it until Ctrl-C (a headless run stops at the end)")
    p.add_argument("--station", metavar="STATION.toml",
                   help="play the wind through this station file's first hoist: its receivers become the "
                        "demo's virtual ports (and its node config the simulated node's, if it is another: then the "
                        "logs in OUT/data); with --serve, a users file it names that is missing is the demo's")
    p.add_argument("--port", type=int, default=None,
                   help="the web face's port of the station the demo writes (default 8080, or a free one)")


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from ropemon.station.monitor import MonitorView
    from ropemon.station.nodefigures import NodeFigures, alarm_settings
    from ropemon.commission.replay import ReplayError, replay
    from ropemon.station.store import Store

    headless = args.headless or args.json or not sys.stdout.isatty()
    station_mode = bool(args.serve or args.station)
    speed = args.speed or (20.0 if headless else (1.0 if args.serve else 4.0))
    out = Path(args.out)
    sim_dir = out / "sim"
    out.mkdir(parents=True, exist_ok=True)
    say = (lambda *a: print(*a, file=sys.stderr)) if headless else print

    def step(text: str) -> float:
        say(f"[demo] {text}")
        return time.monotonic()

    t = step(f"simulating {args.scenario} -> {sim_dir}")
    try:
        simulate(scenario_path(args.scenario), sim_dir, args.seed)
    except (FileNotFoundError, RuntimeError) as e:
        print(f"ropemon demo: {e}", file=sys.stderr)
        return 1
    node_json = sim_dir / "node.json"
    site = NodeFigures.from_node_json(node_json)
    keys = load_node_keys(node_json)
    t = step(f"  done in {time.monotonic() - t:.1f} s; running the node firmware ({args.interpreter})")
    frames_bin = out / "frames.bin"
    try:
        rep = replay(sim_dir / "sensors.rsens", frames_bin, node_json, args.interpreter)
    except ReplayError as e:
        print(f"ropemon demo: {e}", file=sys.stderr)
        return 1
    try:
        sent = read_frames_bin(frames_bin, keys)
    except FrameError as e:
        print(f"ropemon demo: the firmware wrote a frame the host cannot decode: {e}", file=sys.stderr)
        return 1
    t = step(f"  {len(sent.frames)} frames in {time.monotonic() - t:.1f} s; radio model and two virtual serial ports")
    truth = load_truth(sim_dir)
    phys = json.loads(node_json.read_text())["physical"]
    t_truth = truth_time_s(truth, phys["sample_hz"])
    t_frames = np.array([f.time_ms / 1000 for f in sent.frames])
    hoist = hoist_load_from_truth(sim_dir)
    shaft_m = hoist.shaft_m if hoist else float(np.max(truth["cage_depth_m"]))
    rx = radio.paper_receivers(max(shaft_m, 1.0))
    params = radio.RadioParams(shaft_m=max(shaft_m, 1.0))
    result = radio.transmit(zip(t_frames, depth_at(truth, t_truth, t_frames), sent.wires), rx, params, args.seed)

    wind_s = t_frames[-1] - t_frames[0] if len(t_frames) else 0.0
    clock = DemoClock(speed)
    if station_mode:
        from ropemon.lab.demo_station import play_to_station
        try:
            played = play_to_station(args, out, node_json, site, shaft_m, result.deliveries, speed, clock,
                                     headless, step, wind_s)
        except (ValueError, OSError, RuntimeError) as e:
            print(f"ropemon demo: {e}", file=sys.stderr)
            return 2
        if played is None:
            return 2
        host, written, db, keep_serving = played
        step("  the wind is played")
    else:
        db = out / "ropemon.db"
        for p in (db, Path(str(db) + "-wal"), Path(str(db) + "-shm")):
            p.unlink(missing_ok=True)
        store = Store(db)
        view = None if headless else MonitorView(site)
        host = demo_host(keys, alarm_settings(site), clock, store, view, site)
        t = step(f"  playing {wind_s:.0f} s of frames at {speed:g}x real time (about {wind_s / speed:.0f} s)")
        try:
            written = play_to_host(result.deliveries, host, speed, clock,
                                   None if headless else Console())
        finally:
            store.close()
        step(f"  host done in {time.monotonic() - t:.1f} s")
        keep_serving = None

    try:
        acc = accuracy(host.kept.frames, truth, t_truth, site.cylinder_area_m2,
                       site.rated_rope_tension_n or 1.0, 1.0 / phys["frame_hz"])
        plot = plot_demo(acc, out / "demo.png") if acc.get("frames") else None
        summary = summarize(sent, result, host, acc, written, site)
        summary["files"] = {"database": str(db) if db else None, "plot": str(plot) if plot else None,
                            "frames": str(frames_bin), "config": str(node_json), "report": str(out / "report"),
                            "site": json.loads((sim_dir / "truth.json").read_text()).get("site_file")}
        summary["replay"] = rep
        report_text = (trip_report(db, out / "report", site, sim_dir, payload_at(truth["payload_kg"], t_truth))
                       if db is not None else "no trip report: the station keeps no log (station.data_dir)")
        if args.json:
            json.dump(summary, sys.stdout, indent=1, default=float)
            print()
        else:
            print(format_summary(summary))
            print()
            print(report_text)
        (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    finally:
        if keep_serving is not None:
            sys.stdout.flush()
            keep_serving()          # serving until Ctrl-C (--serve in a terminal), then closes the station
    return 0 if summary["host"]["foreign_frames"] == 0 else 1


def pistons(frames: list[Frame], site=None) -> dict:
    """Each rope's piston over the frames received (mm from mid-stroke, x > 0 pulled out by its
    rope): first, last, least and most, and the frames whose stroke flags put it in a margin;
    the end stops and margins where the config gives the stroke."""
    ropes = max((len(f.ropes) for f in frames), default=0)
    out: dict = {"ropes": [], "stroke_mm": None, "margin_mm": None}
    if site is not None and getattr(site, "stroke_m", None):
        out["stroke_mm"] = [round(s * 1e3, 1) for s in site.stroke_m]
        out["margin_mm"] = None if site.stroke_margin_m is None else round(site.stroke_margin_m * 1e3, 1)
    for i in range(ropes):
        xs = [f.ropes[i].position_m for f in frames if i < len(f.ropes) and f.ropes[i].position_m is not None]
        low = sum(1 for f in frames if i < len(f.ropes) and f.stroke_low[i])
        high = sum(1 for f in frames if i < len(f.ropes) and f.stroke_high[i])
        out["ropes"].append({"rope": i + 1, "frames": len(xs),
                             **({"first_mm": round(xs[0] * 1e3, 1), "last_mm": round(xs[-1] * 1e3, 1),
                                 "min_mm": round(min(xs) * 1e3, 1), "max_mm": round(max(xs) * 1e3, 1)} if xs else {}),
                             "frames_retracted_margin": low, "frames_extended_margin": high})
    return out


def alarms_at_end(host: DemoHost) -> dict:
    """The alarms as the wind ends: those raised (every raise), those standing (present) at the
    end, and the raises other than the node falling silent after its last frame (the end of the
    wind): a healthy wind has none."""
    engine = host.alarms.engine
    last = host.kept.last_rx_s
    events = list(engine.events)
    beyond_silence = [e for e in events if e.action == "raise"
                      and not (e.kind == "silent" and last is not None and e.time_s >= last)]
    standing = [a for a in engine.active() if a.present]
    return {"standing": [{"alarm": a.id, "kind": a.kind, "rope": None if a.rope is None else a.rope + 1,
                          "message": a.message} for a in standing],
            "raised_but_end_silence": [{"alarm": e.alarm, "kind": e.kind,
                                        "rope": None if e.rope is None else e.rope + 1, "message": e.message}
                                       for e in beyond_silence]}


def hoist_statuses(host: DemoHost) -> list[dict]:
    """Each node's standing status (`AlarmEngine.hoist_status`: not an alarm) as the wind ends."""
    engine = host.alarms.engine
    out = []
    for node in engine.nodes():
        st = engine.hoist_status(node) if hasattr(engine, "hoist_status") else None
        if st is not None:
            out.append({"node": node, "text": st.text, "hidden_frac": st.hidden_frac, "notes": list(st.notes)})
    return out


def summarize(sent: Sent, result: radio.RadioResult, host: DemoHost, acc: dict, written: dict[str, int],
              site=None) -> dict:
    """Frames sent/received/lost, per-receiver link quality, pistons, the hoist's standing status,
    alarms, accuracy: plain JSON."""
    by_seq = {(f.node, f.seq): f for f in sent.frames}
    session = host.pipeline
    frames, events = host.kept.frames, host.alarms.engine.events
    foreign = sum(1 for f in frames
                  if (f.node, f.seq) not in by_seq or not f.same_payload(by_seq[(f.node, f.seq)]))
    stats = session.hub.merge_stats()
    unique = len(frames)
    receivers = {}
    for name, dec in session.decoders.items():
        r = {"bytes_written": written.get(name, 0),
             "deliveries": len(result.deliveries.get(name, [])),
             **dec.counts.as_dict()}
        for node, st in stats.items():
            share = st["receivers"].get(name, {})
            r["delivered"] = share.get("delivered", 0)
            r["share"] = share.get("share")
            r["share_by_depth"] = [
                (b["depth_from_m"], b["depth_to_m"], b["share"].get(name)) for b in st["by_depth"]]
        receivers[name] = r
    raises: dict[str, int] = {}
    for e in events:
        if e.action == "raise":
            raises[e.kind] = raises.get(e.kind, 0) + 1
    return {
        "node": {"frames_sent": len(sent.frames)},
        "radio": {"frames_no_receiver_got_intact": result.lost,
                  "deliveries": {k: len(v) for k, v in result.deliveries.items()},
                  "bit_errors": {k: sum(d.bit_errors for d in v) for k, v in result.deliveries.items()}},
        "host": {
            "frames_received": unique,
            "frames_lost": len(sent.frames) - unique,
            "gaps_counted": sum(st["lost"] for st in stats.values()),
            "duplicates_dropped": sum(st["duplicates"] for st in stats.values()),
            "foreign_frames": foreign,   # stored frames the node never sent: must be 0
            "stored_frames": host.store.committed_frames if host.store is not None else None,
        },
        "receivers": receivers,
        "alarms": {"raised": raises, "events": [e.to_dict() for e in events][:50], **alarms_at_end(host)},
        "pistons": pistons(frames, site),
        "hoist_status": hoist_statuses(host),
        "accuracy": {k: v for k, v in acc.items() if not k.startswith("_")},
    }


def format_summary(s: dict) -> str:
    h, n = s["host"], s["node"]
    sent = max(n["frames_sent"], 1)
    lines = ["ropemon demo summary", "====================",
             f"frames sent by the node      {n['frames_sent']}",
             f"frames received by the host  {h['frames_received']} ({100 * h['frames_received'] / sent:.1f} %)",
             f"frames lost                  {h['frames_lost']} (host counted {h['gaps_counted']} in sequence gaps)",
             f"duplicates dropped           {h['duplicates_dropped']}",
             f"frames not sent by the node  {h['foreign_frames']} (corrupted frames accepted: must be 0)",
             "", "link quality per receiver (share of the node's frames it delivered)"]
    for name, r in s["receivers"].items():
        share = f"{100 * r['share']:.1f} %" if r.get("share") is not None else "--"
        lines.append(f"  {name:10} {share:>8}  crc fail {r['crc_fail']}  malformed {r['malformed']}  "
                     f"mac fail {r['mac_fail']}  bytes discarded {r['bytes_discarded']}")
        bins = [f"{a:.0f}..{b:.0f} m {100 * sh:.0f}%" for a, b, sh in r.get("share_by_depth", []) if sh is not None]
        for k in range(0, len(bins), 5):
            lines.append("      " + "  ".join(bins[k:k + 5]))
    lines += format_pistons(s.get("pistons") or {})
    for st in s.get("hoist_status") or []:
        lines += [""] + _wrap(f"hoist status, node {st['node']} (standing, not an alarm): {st['text']}")
        for n in st["notes"]:
            lines += _wrap("  " + n, "    ")
    al = s["alarms"]
    raised = al["raised"]
    lines += ["", "alarms raised: " + (", ".join(f"{k} x{v}" for k, v in raised.items()) or "none")]
    by_rope: dict[int, list[str]] = {}
    for e in al["events"]:
        if e["action"] == "raise" and e.get("rope") is not None and e["kind"] not in by_rope.get(e["rope"] + 1, []):
            by_rope.setdefault(e["rope"] + 1, []).append(e["kind"])
    if by_rope:
        lines += _wrap("  on the ropes: " + "; ".join(f"rope {r} {', '.join(k)}" for r, k in sorted(by_rope.items())),
                       "    ")
    for e in al["events"][:8]:
        lines += _wrap(f"  {e['action']:5} {e['alarm']:22} {e['message']}", " " * 31)
    if "standing" in al:
        standing = [a for a in al["standing"] if a["kind"] != "silent"]
        silent = len(al["standing"]) - len(standing)
        if not al["raised_but_end_silence"]:
            lines.append("at the end of the wind: no alarm" + (" but the node silent (the wind ended)" if silent
                                                               else ""))
        else:
            lines.append(f"at the end of the wind: {len(standing)} alarm(s) standing"
                         + (", and the node silent (the wind ended)" if silent else ""))
            for a in standing:
                lines += _wrap(f"  {a['alarm']:22} {a['message']}", " " * 25)
    acc = s["accuracy"]
    if acc.get("frames"):
        c, r = acc["compensated"], acc["raw"]
        lines += ["", f"accuracy against the simulator's truth ({acc['frames']} frames, node-time aligned, "
                      "% of rated rope tension; total: % of ropes x rated)",
                  f"  {'':14}{'rope rms':>10}{'rope peak':>11}{'total rms':>11}{'total peak':>12}",
                  f"  {'raw p x A':14}{r['rope_rms_pct']:10.2f}{r['rope_peak_pct']:11.2f}"
                  f"{r['total_rms_pct']:11.2f}{r['total_peak_pct']:12.2f}",
                  f"  {'compensated':14}{c['rope_rms_pct']:10.2f}{c['rope_peak_pct']:11.2f}"
                  f"{c['total_rms_pct']:11.2f}{c['total_peak_pct']:12.2f}"]
        lines.append("  per rope rms, compensated: " + "  ".join(f"{v:.2f}" for v in c["per_rope_rms_pct"])
                     + "   raw: " + "  ".join(f"{v:.2f}" for v in r["per_rope_rms_pct"]))
        pr = acc.get("pithead_rest")
        if pr:
            tt = pr["true_total_kN"]
            lines.append(f"  pithead rest after the wind (sum): true {tt:.1f} kN, raw {pr['raw_total_kN']:.1f} kN "
                         f"({(pr['raw_total_kN'] - tt) / tt * 100:+.1f} %), compensated "
                         f"{pr['compensated_total_kN']:.1f} kN ({(pr['compensated_total_kN'] - tt) / tt * 100:+.1f} %)")
    f = s.get("files", {})
    lines += ["", f"log: {f.get('database')}   plot: {f.get('plot')}",
              f"trip table again: ropemon report {f.get('database')} --config {f.get('config')}"
              + (f" --site {f['site']}" if f.get("site") else "")]
    return "\n".join(lines)


def _wrap(text: str, indent: str = "  ", width: int = 80) -> list[str]:
    import textwrap

    return textwrap.wrap(text, width, subsequent_indent=indent, break_on_hyphens=False) or [""]


def format_pistons(p: dict) -> list[str]:
    """The summary's piston lines: one per rope, within 80 columns."""
    if not p.get("ropes") or not any(r["frames"] for r in p["ropes"]):
        return ["", "pistons: the frames carry no piston positions (layout version 2)"] if p.get("ropes") else []
    head = "pistons, mm from mid-stroke (+: pulled out)"
    if p.get("stroke_mm"):
        head += f"; end stops at +-{p['stroke_mm'][0] / 2:.0f}"
        if p.get("margin_mm") is not None:
            head += f", margins {p['margin_mm']:g} inside them"
    lines = ["", head, f"  {'':6}{'first':>8}{'last':>8}{'least':>8}{'most':>8}   in a margin (frames)"]
    for r in p["ropes"]:
        if not r["frames"]:
            lines.append(f"  rope {r['rope']}  no position")
            continue
        where = ", ".join(f"{what} {n}" for what, n in (("retracted", r["frames_retracted_margin"]),
                                                          ("extended", r["frames_extended_margin"])) if n) or "never"
        lines.append(f"  rope {r['rope']}{r['first_mm']:+8.1f}{r['last_mm']:+8.1f}{r['min_mm']:+8.1f}"
                     f"{r['max_mm']:+8.1f}   {where}")
    return lines


def trip_report(db: Path, out_dir: Path, site, sim_dir: Path, payload_kg) -> str:
    """The paper's field-test table for the demo's log (report.py)."""
    from ropemon.station.report import write_report
    from ropemon.station.store import Store

    load = hoist_load_from_truth(sim_dir)
    with Store(db, readonly=True) as st:
        text, _ = write_report(st, out_dir, site.cylinder_area_m2, load, payload_kg,
                               shaft_m=load.shaft_m if load else None,
                               stroke_m=list(site.stroke_m) or None, margin_m=site.stroke_margin_m)
    return text


def hoist_load_from_truth(sim_dir: Path):
    """Cage, tail ropes and shaft of the simulated hoist (truth.json), or None."""
    from ropemon.station.report import HoistLoad

    try:
        tj = json.loads((sim_dir / "truth.json").read_text())
        tail = tj["tail"]
        return HoistLoad(float(tj["cage_mass_kg"]), int(tail["count"]), float(tail["kg_per_m"]),
                         float(tail["loop_depth_m"]))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def payload_at(payload: np.ndarray, t: np.ndarray):
    """The payload in the cage at a node time (the simulator's log of loading), for the
    report's theoretical load at each rest it averages."""

    def at(t_s: float) -> float:
        return float(payload[min(int(np.searchsorted(t, t_s)), len(t) - 1)])

    return at


def scenario_path(name: str) -> str:
    """A scenario file, or a name from scenarios/ (paper-field-trip, short-test)."""
    if Path(name).is_file():
        return name
    cand = FIRMWARE_DIR.parent / "scenarios" / f"{name}.toml"
    if cand.is_file():
        return str(cand)
    raise FileNotFoundError(f"scenario {name!r}: neither a file nor scenarios/{name}.toml")
