"""The simulation HAL end to end: `micropython -m ropenode.sim_main` on a .rsens file."""
from __future__ import annotations

import os
import struct
import subprocess
import sys
from pathlib import Path

from streams_cpython import random_stream

from ropemon.station import protocol
from ropemon.firmware import FIRMWARE_DIR, node_module
from ropemon.commission.nodejson import EXAMPLE_KEY, example_physical

MICROPYTHON = Path(sys.executable).parent / "micropython"
L = node_module("layout")


def _write_rsens(path: Path, recs) -> None:
    with path.open("wb") as f:
        f.write(struct.pack("<4sHHHH", b"RSNS", 1, recs.shape[1] // 2 - 2, 200, 0))
        f.write(recs.astype("<u2").tobytes())


def _run_mp(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, MICROPYPATH=str(FIRMWARE_DIR))
    return subprocess.run([str(MICROPYTHON), "-m", "ropenode.sim_main", *args], env=env,
                          capture_output=True, text=True, timeout=120)


def test_unix_port_and_cpython_write_identical_frames(tmp_path):
    recs = random_stream(example_physical(), 20, 9, faults=True)
    src = tmp_path / "in.rsens"
    _write_rsens(src, recs)
    cfg = FIRMWARE_DIR / "node.json"
    r = _run_mp(str(cfg), str(src), str(tmp_path / "mp.bin"))
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["samples", "4000", "frames", "200"]
    hal_sim = node_module("hal_sim")
    assert hal_sim.run_sim(str(cfg), str(src), str(tmp_path / "cp.bin")) == (4000, 200)
    mp = (tmp_path / "mp.bin").read_bytes()
    assert mp == (tmp_path / "cp.bin").read_bytes()
    assert mp[:1] == b"\x00" and mp.count(b"\x00") == 400  # 0x00 before and after each frame
    bodies = [b for b in mp.split(b"\x00") if b]
    assert len(bodies) == 200
    key = {1: EXAMPLE_KEY}
    frames = [protocol.decode_raw(protocol.decode_wire(b), keys=key) for b in bodies]
    assert [f.seq for f in frames] == list(range(200))


def test_missing_config_gives_status_frames(tmp_path):
    recs = random_stream(example_physical(), 1, 9)
    src = tmp_path / "in.rsens"
    _write_rsens(src, recs)
    r = _run_mp(str(tmp_path / "none.json"), str(src), str(tmp_path / "out.bin"))
    assert r.returncode == 0 and "config-fault" in r.stderr
    bodies = [b for b in (tmp_path / "out.bin").read_bytes().split(b"\x00") if b]
    frames = [protocol.decode_raw(protocol.decode_wire(b)) for b in bodies]
    assert len(frames) == 10
    assert all(f.kind == L.KIND_STATUS and f.status & L.ST_CONFIG_FAULT for f in frames)


def test_bad_stream_is_refused_clearly(tmp_path):
    src = tmp_path / "bad.rsens"
    src.write_bytes(b"NOPE" + bytes(20))
    r = _run_mp(str(FIRMWARE_DIR / "node.json"), str(src), str(tmp_path / "o.bin"))
    assert r.returncode == 1 and "not a version-1 .rsens" in r.stderr
