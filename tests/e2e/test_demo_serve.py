"""`ropemon demo --serve`: the simulated wind through a station (Station) with its web face.

Headless (stdout not a terminal) the demo serves while the wind plays and stops at the end;
the station it writes (OUT/station.toml, OUT/users.toml with a new operator password) and
its log (OUT/demo.db) stay. `--station` plays through a given station file's first hoist.
"""
import json
import os
import re
import sqlite3
import stat
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
pytest.importorskip("starlette")


def _demo(out: Path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "ropemon.cli", "demo", "--scenario", "short-test", "--out", str(out),
           "--speed", "40", "--interpreter", "cpython", *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT)


def test_demo_serves_the_wind_through_a_station_and_stops_at_the_end_headless(tmp_path):
    out = tmp_path / "demo"
    r = _demo(out, "--serve", "--port", str(_free()))
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert r.stdout.startswith("ropemon demo summary")
    assert re.search(r"web: http://127\.0\.0\.1:\d+/ \(1 hoist; view without login; 1 user", r.stderr), r.stderr
    assert "log in as demo / " in r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["host"]["foreign_frames"] == 0 and summary["host"]["frames_received"] > 0
    assert summary["files"]["database"] == str(out / "demo.db")
    with sqlite3.connect(out / "demo.db") as db:
        assert db.execute("SELECT count(*) FROM frames").fetchone()[0] == summary["host"]["frames_received"]
    assert stat.S_IMODE(os.stat(out / "users.toml").st_mode) == 0o600
    # the same station file again: its log holds the node's frames, so the demo's would be replays
    r = _demo(out, "--station", str(out / "station.toml"))
    assert r.returncode == 2 and "refused as replays" in r.stderr, r.stderr[-2000:]


def _free() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
