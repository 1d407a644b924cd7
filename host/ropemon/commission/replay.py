"""`ropemon replay SENSORS [--out FRAMES.bin] [--db FILE]`: the node firmware on a sensor stream.

Runs the firmware's simulation HAL (`ropenode.hal_sim`) on a recorded or
simulated `.rsens` stream and writes the bytes the node would have sent to the
radio (COBS frames, each ended by 0x00). By default the firmware runs in the
real `micropython` unix port, as on a node; `--interpreter cpython` runs the
same modules under CPython (the bytes must be identical). This is how a user
regression-tests the algorithms against field recordings, and it is the first
link of `ropemon demo`.

With `--db` the frames then go through the hoist-room station's own data path
(the station `ropemon.station.assembly.build_hoist` builds: decode with the node's
key, merge, alarm engine, SQLite store), on a clock that is the node's frame time, so alarm
debounces and trips are those of the recording; `ropemon report` and
`ropemon export` read the database as they read a live log.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

from ropemon.firmware import FIRMWARE_DIR, micropython_command
from ropemon.commission.reference import RS, RSENS_HEADER
from ropemon.station import files

if TYPE_CHECKING:
    from ropemon.station.assembly import HoistSpec

DEFAULT_CONFIG = FIRMWARE_DIR / "node.json"
RECEIVER = "replay"   # the receiver name of the replayed frames in the database
TICK_S = 0.25         # the station's loop ticks (silent alarm, store flush) this often, in node time


class ReplayError(RuntimeError):
    """The replay could not run; the message says why."""


def read_header(path: Path) -> dict:
    """Check a .rsens file (docs/data-formats.md) before handing it to the firmware."""
    # a regular file (a FIFO or /dev/zero would feed the firmware for ever) of at most files.MAX_RSENS
    with files.open_file(path, "sensor stream", files.MAX_RSENS, ReplayError) as fh:
        size = os.fstat(fh.fileno()).st_size
        try:
            head = fh.read(RSENS_HEADER.size)
        except OSError as e:
            raise ReplayError(f"{path}: cannot read: {e.strerror or e}") from None
    if len(head) < RSENS_HEADER.size:
        raise ReplayError(f"{path}: too short for a .rsens header ({len(head)} bytes < {RSENS_HEADER.size})")
    magic, version, ropes, sample_hz, _ = RSENS_HEADER.unpack(head)
    if magic != RS.MAGIC:
        raise ReplayError(f"{path}: not a sensor stream (magic {magic!r}, expected {RS.MAGIC!r})")
    if version != 1:
        raise ReplayError(f"{path}: sensor stream version {version} not supported (this ropemon reads 1)")
    if not 1 <= ropes <= 4 or sample_hz == 0:
        raise ReplayError(f"{path}: header says {ropes} ropes at {sample_hz} Hz: not a valid stream")
    rec = 2 * (2 * ropes + 4)
    body = size - RSENS_HEADER.size
    return {"ropes": ropes, "sample_hz": sample_hz, "samples": body // rec, "trailing_bytes": body % rec}


def replay(sensors: str | Path, out: str | Path, config: str | Path = DEFAULT_CONFIG,
           interpreter: str = "micropython", timeout_s: float = 600.0) -> dict:
    """Run the firmware on `sensors`, write the radio bytes to `out`; return figures
    (samples, frames, bytes, wall_s, interpreter). Raises ReplayError."""
    sensors, out, config = Path(sensors), Path(out), Path(config)
    head = read_header(sensors)
    if head["trailing_bytes"]:
        print(f"ropemon replay: {sensors}: {head['trailing_bytes']} bytes after the last whole record "
              "are ignored (truncated recording?)", file=sys.stderr)
    if not config.exists():
        # The node itself would run on with config-fault status frames; a user who
        # named a file that is not there made a mistake, so say it.
        raise ReplayError(f"{config}: no such config file")
    # The node refuses a config it cannot use (and says why); a file that is no JSON object
    # at all, a FIFO, a device or a huge file is refused here, before the firmware runs.
    if not isinstance(files.read_json(config, "node.json", files.MAX_NODE_JSON, ReplayError, allow_nan=True), dict):
        raise ReplayError(f"{config}: not a node config (not a JSON object)")
    out.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if interpreter == "micropython":
        env = dict(os.environ, MICROPYPATH=str(FIRMWARE_DIR))
        try:
            exe = micropython_command()
        except FileNotFoundError as e:
            raise ReplayError(str(e)) from None
        cmd = [exe, "-m", "ropenode.sim_main", str(config), str(sensors), str(out)]
        try:
            r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise ReplayError(f"micropython did not finish within {timeout_s:.0f} s") from None
        if r.stderr.strip():
            print(r.stderr.strip(), file=sys.stderr)  # e.g. the node's config refusal: the user must see it
        if r.returncode != 0:
            raise ReplayError(f"the firmware under micropython failed (exit {r.returncode}): "
                              f"{(r.stderr or r.stdout).strip()[-1000:]}")
        try:
            words = r.stdout.split()[-4:]   # "samples N frames M"
            samples, frames = int(words[1]), int(words[3])
        except (ValueError, IndexError):
            raise ReplayError(f"unexpected output from the firmware: {r.stdout.strip()[-300:]!r}") from None
    elif interpreter == "cpython":
        from ropemon.firmware import node_module
        hal_sim = node_module("hal_sim")
        try:
            samples, frames = hal_sim.run_sim(str(config), str(sensors), str(out))
        except (OSError, ValueError) as e:
            raise ReplayError(f"the firmware under CPython failed: {e}") from None
    else:
        raise ReplayError(f"unknown interpreter {interpreter!r} (micropython or cpython)")
    return {"interpreter": interpreter, "samples": samples, "frames": frames,
            "bytes": out.stat().st_size, "wall_s": time.perf_counter() - t0,
            "stream_s": samples / head["sample_hz"]}


class ReplayClock:
    """The station's clock during a replay: the node's time of the frame being fed, in s."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def frame_time_s(body: bytes) -> float | None:
    """The node's time (s) of one wire frame (COBS body without the 0x00), None if it does not parse.
    Authenticity is checked later, by the session's decoder."""
    from ropemon.station.protocol import FrameError, decode_raw, decode_wire
    try:
        return decode_raw(decode_wire(body), None).time_ms / 1000.0
    except FrameError:
        return None


def replay_spec(config: str | Path) -> "HoistSpec":
    """The replay's one hoist (`assembly.HoistSpec`): figures, key and alarm settings from a
    node.json, as `ropemon monitor --config` takes them. Raises ReplayError."""
    from ropemon.station.assembly import HoistSpec
    from ropemon.station.nodefigures import NodeFigures, alarm_settings
    from ropemon.station.protocol import load_node_keys
    try:
        keys = load_node_keys(config)
        figures = NodeFigures.from_node_json(config)
        return HoistSpec(RECEIVER, figures, keys, alarm_settings(figures))
    except ValueError as e:
        raise ReplayError(str(e)) from None


def replay_to_store(frames_bin: str | Path, config: str | Path, db: str | Path) -> dict:
    """Feed the radio bytes of a replay through the station's data path into a new database.

    The frames are decoded with the node's key from `config`, merged, run through the
    alarm engine with the thresholds `ropemon monitor --config` would use, and logged,
    one receiver (`replay`), on a clock that is the frames' node time (s since the node
    started; it is kept from going back if the node restarted within the recording): the
    alarms' timing, the events' and link statistics' times and the frames' rx times.
    Returns figures: frames, trips, decode counts and `alarms` {kind: {"raise": n, "clear": n}}.
    Raises ReplayError (config unreadable, database exists or unusable).
    """
    from ropemon.station import assembly
    from ropemon.station.store import Store, StoreError

    frames_bin, db = Path(frames_bin), Path(db)
    spec = replay_spec(config)
    if db.exists():
        raise ReplayError(f"{db}: exists; --db writes a new log (remove it or name another file)")
    db.parent.mkdir(parents=True, exist_ok=True)
    try:
        store = Store(db, batch_frames=1000, synchronous="NORMAL")
    except StoreError as e:
        raise ReplayError(str(e)) from None
    clock = ReplayClock()
    hoist = assembly.build_hoist(spec, clock, wall=clock, store=store, db_path=db)
    session = hoist.pipeline
    offset = 0.0                       # added after a restart of the node's clock
    last = next_tick = None
    try:
        for body in files.read_bytes(frames_bin, "radio bytes", files.MAX_FRAMES_BIN, ReplayError).split(b"\x00")[:-1]:
            t = frame_time_s(body) if body else None
            if t is not None:
                if last is not None and t + offset < last:
                    offset = last - t
                t += offset
                if next_tick is None:
                    next_tick = t
                while next_tick <= t:      # the station's loop runs on while frames are missing
                    clock.t = next_tick
                    session.tick()
                    next_tick += TICK_S
                clock.t = last = t
            session.feed(RECEIVER, body + b"\x00")
        session.close()
        counts = session.decoders[RECEIVER].counts.as_dict() if RECEIVER in session.decoders else {}
        alarms: dict[str, Counter] = {}
        for ev in store.events():
            if ev["action"] in ("raise", "clear"):
                alarms.setdefault(ev["kind"], Counter())[ev["action"]] += 1
        fig = {"frames": store.committed_frames, "trips": len(store.trips()), "decode": counts,
               "alarms": {k: {"raise": c["raise"], "clear": c["clear"]} for k, c in sorted(alarms.items())},
               "still_raised": sorted(a.id for a in hoist.alarms.engine.active() if a.present)}
    finally:
        session.hub.stop()
        store.close()
    return fig


def alarm_summary(fig: dict) -> str:
    """The alarm events of a replay, one line per kind (raise and clear counts)."""
    if not fig["alarms"]:
        return "alarm events: none"
    width = max(len(k) for k in fig["alarms"])
    rows = ["alarm events:", f"  {'kind':{width}}  raise  clear"]
    rows += [f"  {k:{width}}  {c['raise']:5d}  {c['clear']:5d}" for k, c in fig["alarms"].items()]
    if fig["still_raised"]:
        rows.append("  raised at the end: " + ", ".join(fig["still_raised"]))
    return "\n".join(rows)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("sensors", help="sensor stream (.rsens, docs/data-formats.md)")
    p.add_argument("--out", help="file for the radio bytes (COBS frames, 0x00-terminated)")
    p.add_argument("--db", help="new SQLite log: the frames through the station's decode, alarms and store "
                                "(for ropemon report / export)")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="node.json (default: firmware/node.json)")
    p.add_argument("--interpreter", choices=("micropython", "cpython"), default="micropython",
                   help="run the firmware in the micropython unix port (default) or under CPython")


def run(args: argparse.Namespace) -> int:
    if not args.out and not args.db:
        print("ropemon replay: give --out FRAMES.bin, --db FILE or both", file=sys.stderr)
        return 2
    if args.db and Path(args.db).exists():
        print(f"ropemon replay: {args.db}: exists; --db writes a new log (remove it or name another file)",
              file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory(prefix="ropemon-replay-") as tmp:
        out = args.out or str(Path(tmp) / "frames.bin")
        try:
            if args.db:
                replay_spec(args.config)      # refuse a config the station cannot use before the firmware runs
            fig = replay(args.sensors, out, args.config, args.interpreter)
            print(f"{args.sensors}: {fig['samples']} samples ({fig['stream_s']:.1f} s of node time) -> "
                  f"{fig['frames']} frames, {fig['bytes']} bytes" + (f" in {args.out}" if args.out else "")
                  + f" ({fig['interpreter']}, {fig['wall_s']:.1f} s)")
            if args.db:
                st = replay_to_store(out, args.config, args.db)
        except ReplayError as e:
            print(f"ropemon replay: {e}", file=sys.stderr)
            return 1
    if args.db:
        d = st["decode"]
        bad = sum(d.get(k, 0) for k in ("crc_fail", "malformed", "mac_fail", "replayed"))
        print(f"{args.db}: {st['frames']} frames stored, {st['trips']} trips"
              + (f", {bad} frames refused by the decoder ({d})" if bad else ""))
        print(alarm_summary(st))
        if bad:   # the node's own bytes with its own key: a refusal means the log is incomplete
            print(f"ropemon replay: {bad} frames refused by the decoder: {args.db} lacks them", file=sys.stderr)
            return 1
    return 0
