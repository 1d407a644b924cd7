"""End to end over ptys: simulator (short-test) -> firmware in the real `micropython`
unix port -> radio model -> two pty pairs -> pyserial -> decode, merge, alarms, SQLite
-> summary against the truth. Exactly what `make demo` does, on the short scenario."""
import json
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    if shutil.which("micropython", path=str(Path(sys.executable).parent)) is None:
        pytest.fail("the micropython unix port is not installed in the venv (make test installs it)")
    out = tmp_path_factory.mktemp("demo")
    # No --headless: a run whose stdout is not a terminal must print the summary only.
    cmd = [sys.executable, "-m", "ropemon.cli", "demo", "--scenario", "short-test", "--out", str(out),
           "--speed", "40"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=240, cwd=ROOT)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert r.stdout.startswith("ropemon demo summary") and "\x1b" not in r.stdout
    return out, json.loads((out / "summary.json").read_text()), r.stdout


def test_every_frame_accounted_for_and_none_corrupted(demo_run):
    out, s, _ = demo_run
    sent = s["node"]["frames_sent"]
    h = s["host"]
    assert sent > 50
    assert h["foreign_frames"] == 0
    assert h["frames_received"] + h["frames_lost"] == sent
    assert h["frames_received"] > 0.5 * sent
    assert h["stored_frames"] == h["frames_received"]
    db = sqlite3.connect(out / "ropemon.db")
    rows = db.execute("SELECT node, seq FROM frames").fetchall()
    assert len(rows) == len(set(rows)) == h["frames_received"]     # logged once each


def test_both_receivers_seen_and_link_quality_reported(demo_run):
    _, s, _ = demo_run
    rx = s["receivers"]
    assert set(rx) == {"pithead", "mid-shaft"}
    for r in rx.values():
        assert r["bytes_written"] > 0 or r["deliveries"] == 0
        assert r["share"] is None or 0.0 <= r["share"] <= 1.0


def test_accuracy_against_truth_is_reported(demo_run):
    out, s, _ = demo_run
    acc = s["accuracy"]
    assert acc["frames"] == s["host"]["frames_received"]
    for kind in ("raw", "compensated"):
        assert len(acc[kind]["per_rope_rms_pct"]) == 4
        assert acc[kind]["total_rms_pct"] >= 0
    assert Path(s["files"]["plot"]).read_bytes()[:4] == b"\x89PNG"


def test_replay_under_micropython_matches_cpython(demo_run, tmp_path):
    out, s, _ = demo_run
    sensors = out / "sim" / "sensors.rsens"
    cfg = out / "sim" / "node.json"
    cp = tmp_path / "cp.bin"
    r = subprocess.run([sys.executable, "-m", "ropemon.cli", "replay", str(sensors), "--out", str(cp),
                        "--config", str(cfg), "--interpreter", "cpython"], capture_output=True, text=True,
                       timeout=120, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert cp.read_bytes() == (out / "frames.bin").read_bytes()


def test_firmware_frames_through_two_noisy_receivers_recovered_exactly_once(demo_run):
    """The node's real frames (from micropython) through two receivers that both hear
    the cage, with heavy bit errors: every intact frame is recovered exactly once,
    equal to what the node sent, and nothing corrupted gets through."""
    from ropemon.lab import radio
    from ropemon.lab.demo import DemoClock, demo_host, play_to_host, read_frames_bin, summarize
    from ropemon.station.nodefigures import NodeFigures, alarm_settings
    from ropemon.station.protocol import load_node_keys

    out, _, _ = demo_run
    keys = load_node_keys(out / "sim" / "node.json")
    sent = read_frames_bin(out / "frames.bin", keys)
    t = [f.time_ms / 1000 for f in sent.frames]
    both = (radio.Receiver("pithead", 0.0, 0.0, 100.0), radio.Receiver("mid-shaft", 50.0, 100.0, 100.0))
    params = radio.RadioParams(shaft_m=100.0, loss_near=0.1, loss_edge=0.3, ber_near=3e-4, ber_edge=3e-3)
    result = radio.transmit(zip(t, [10.0] * len(t), sent.wires), both, params, seed=11)
    # Recoverable: a copy arrived without bit errors. Its own leading 0x00 ends whatever came
    # before it on the line, so a damaged frame before it cannot take it down too.
    recoverable = {sent.frames[d.frame_index].seq
                   for deliveries in result.deliveries.values() for d in deliveries if d.bit_errors == 0}
    assert len(recoverable) < len(sent.frames)       # the radio really lost some
    clock = DemoClock(speed=40.0)
    session = demo_host(keys, alarm_settings(NodeFigures.from_node_json(out / "sim" / "node.json")), clock)
    written = play_to_host(result.deliveries, session, 40.0, clock)
    s = summarize(sent, result, session, {"frames": 0}, written)
    got = [f.seq for f in session.kept.frames]
    assert s["host"]["foreign_frames"] == 0
    assert len(got) == len(set(got))
    assert set(got) == recoverable
    assert s["host"]["duplicates_dropped"] > 0
    assert sum(r["crc_fail"] + r["malformed"] for r in s["receivers"].values()) > 0


def test_demo_runs_with_the_slack_alarm_on_and_no_false_slack(demo_run):
    """The simulator's node.json (built by `ropemon config`'s code) carries the empty cage
    load, so the demo's alarms include SLACK; a normal wind must not raise it."""
    from ropemon.station.nodefigures import NodeFigures, alarm_settings

    out, s, _ = demo_run
    site = NodeFigures.from_node_json(out / "sim" / "node.json")
    settings = alarm_settings(site)
    assert site.conveyance_weight_n and settings.slack_dan == round(0.6 * site.conveyance_weight_n / 10 / 4)
    db = sqlite3.connect(out / "ropemon.db")
    assert db.execute("SELECT count(*) FROM events WHERE kind = 'slack'").fetchone()[0] == 0
