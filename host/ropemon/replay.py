"""`ropemon replay SENSORS --out FRAMES.bin`: the node firmware on a sensor stream.

Runs the firmware's simulation HAL (`ropenode.hal_sim`) on a recorded or
simulated `.rsens` stream and writes the bytes the node would have sent to the
radio (COBS frames, each ended by 0x00). By default the firmware runs in the
real `micropython` unix port, as on a node; `--interpreter cpython` runs the
same modules under CPython (the bytes must be identical). This is how a user
regression-tests the algorithms against field recordings, and it is the first
link of `ropemon demo`.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

from ropemon.firmware import FIRMWARE_DIR, micropython_command
from ropemon.reference import RS, RSENS_HEADER

DEFAULT_CONFIG = FIRMWARE_DIR / "node.json"


class ReplayError(RuntimeError):
    """The replay could not run; the message says why."""


def read_header(path: Path) -> dict:
    """Check a .rsens file (docs/data-formats.md) before handing it to the firmware."""
    try:
        size = path.stat().st_size
        with path.open("rb") as fh:
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
    if not config.is_file():
        # The node itself would run on with config-fault status frames; a user who
        # named a file that is not there made a mistake, so say it.
        raise ReplayError(f"{config}: no such config file")
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


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("sensors", help="sensor stream (.rsens, docs/data-formats.md)")
    p.add_argument("--out", required=True, help="file for the radio bytes (COBS frames, 0x00-terminated)")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="node.json (default: firmware/node.json)")
    p.add_argument("--interpreter", choices=("micropython", "cpython"), default="micropython",
                   help="run the firmware in the micropython unix port (default) or under CPython")


def run(args: argparse.Namespace) -> int:
    try:
        fig = replay(args.sensors, args.out, args.config, args.interpreter)
    except ReplayError as e:
        print(f"ropemon replay: {e}", file=sys.stderr)
        return 1
    print(f"{args.sensors}: {fig['samples']} samples ({fig['stream_s']:.1f} s of node time) -> "
          f"{fig['frames']} frames, {fig['bytes']} bytes in {args.out} "
          f"({fig['interpreter']}, {fig['wall_s']:.1f} s)")
    return 0
