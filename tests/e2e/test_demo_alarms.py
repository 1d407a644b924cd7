"""What `ropemon demo` shows of the equalizer: on the healthy default wind (what `make demo`
plays, through the station it serves, headless here) no alarm but the end-of-wind silence, the
pistons and the hoist's standing status; `--scenario fault-stroke-limit` raises the stroke
limit on the rope whose piston reaches its end, and on no other."""
import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _free() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _demo(out: Path, *extra: str) -> tuple[dict, str]:
    cmd = [sys.executable, "-m", "ropemon.cli", "demo", "--out", str(out), "--speed", "40", *extra]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=400, cwd=ROOT)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert r.stdout.startswith("ropemon demo summary")
    return json.loads((out / "summary.json").read_text()), r.stdout


def test_make_demo_on_the_healthy_default_wind_ends_with_no_alarm_but_the_silence(tmp_path):
    pytest.importorskip("starlette")
    s, text = _demo(tmp_path / "demo", "--serve", "--port", str(_free()))
    al = s["alarms"]
    assert al["raised_but_end_silence"] == [], al["raised_but_end_silence"]
    assert all(a["kind"] == "silent" for a in al["standing"]), al["standing"]
    assert "at the end of the wind: no alarm" in text
    assert "DEVIATION POSSIBLE" not in text and "deviation_possible" not in text
    # the pistons, from the frames' positions: every rope, inside its stroke, never in a margin
    p = s["pistons"]
    assert p["stroke_mm"] == [200.0] * 4 and p["margin_mm"] == 10.0
    for r in p["ropes"]:
        assert r["frames"] == s["host"]["frames_received"]
        assert -90.0 < r["min_mm"] <= r["max_mm"] < 90.0
        assert r["frames_retracted_margin"] == r["frames_extended_margin"] == 0
    assert "pistons, mm from mid-stroke" in text and "end stops at +-100" in text
    # the hoist's standing status (the imbalance the seals can hide), not an alarm
    (st,) = s["hoist_status"]
    assert st["node"] == 1 and 0.0 < st["hidden_frac"] and "seals can hide" in st["text"]
    assert "hoist status, node 1 (standing, not an alarm)" in text
    shown = text.split("pistons, mm from mid-stroke")[1].split("accuracy against")[0]
    assert all(len(line) <= 80 for line in shown.splitlines()), shown   # pistons, status, alarms


def test_demo_scenario_stroke_limit_alarms_on_the_rope_at_its_end(tmp_path):
    s, text = _demo(tmp_path / "demo", "--scenario", "fault-stroke-limit", "--interpreter", "cpython")
    strokes = [e for e in s["alarms"]["events"] if e["kind"] == "stroke_limit" and e["action"] == "raise"]
    assert strokes and {e["rope"] for e in strokes} == {0}, strokes       # rope 1 (from 0 in events)
    assert any(a["kind"] == "stroke_limit" and a["rope"] == 1 for a in s["alarms"]["standing"])
    r1, *others = s["pistons"]["ropes"]
    assert r1["frames_extended_margin"] > 0 and r1["max_mm"] > 90.0
    assert all(r["frames_extended_margin"] == r["frames_retracted_margin"] == 0 for r in others)
    assert "rope 1 deviation, stroke_limit" in text or "rope 1 stroke_limit" in text
    assert "raise stroke_limit:n1:r0" in text


def test_demo_refuses_an_unknown_scenario_by_name(tmp_path):
    cmd = [sys.executable, "-m", "ropemon.cli", "demo", "--scenario", "no-such-scenario", "--out", str(tmp_path)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert r.returncode != 0 and "no-such-scenario" in r.stderr and "Traceback" not in r.stderr
