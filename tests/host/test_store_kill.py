"""The store's two early commits survive SIGKILL: an alarm event is on disk as soon as
`add_event` returns (with the frames pending before it), and a pending frame once
`max_latency_s` has passed and the store was flushed (the station's tick) or given another
frame. A child process writes through Store with a batch far larger than the frames it
adds, says when it is there, and is killed; the file is then read with plain sqlite3.
"""
from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

HOST = Path(__file__).resolve().parents[2] / "host"
LATENCY_S = 0.2

CHILD = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {host!r})
    from ropemon.firmware import install_shim; install_shim()
    from ropemon.station.alarms import AlarmEvent
    from ropemon.station.decoder import StreamDecoder
    from ropemon.station.protocol import encode_frame
    from ropemon.station.store import Store

    def frame(seq):
        _, w = encode_frame(node=1, seq=seq, ropes=[(5000 + seq, 0, 0, 0)] * 4)
        return StreamDecoder().feed(w)[0]

    mode = sys.argv[2]
    s = Store(sys.argv[1], batch_frames=1000, max_latency_s={latency!r})
    s.add_frame("a", frame(1), 1.0)
    if mode == "event":
        s.add_event(AlarmEvent(time_s=1.0, action="raise", alarm="deviation:n1:r3", kind="deviation",
                               node=1, rope=3, value=0.2, threshold=0.1, message="rope 4 off the mean"))
    elif mode == "flush":
        time.sleep(1.5 * {latency!r})
        s.flush()
    elif mode == "next-frame":
        time.sleep(1.5 * {latency!r})
        s.add_frame("a", frame(2), 2.0)
    print("there", s.pending_frames, flush=True)
    time.sleep(60)
""")


def _write_and_kill(tmp_path: Path, mode: str) -> tuple[list[int], list[tuple], int]:
    """Run the child in `mode` until it says its writes returned, SIGKILL it; return the frame
    seqs and events the file holds, and the frames the child still had pending."""
    db = tmp_path / "k.db"
    script = tmp_path / "child.py"
    script.write_text(CHILD.format(host=str(HOST), latency=LATENCY_S))
    proc = subprocess.Popen([sys.executable, str(script), str(db), mode], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    assert line.startswith("there "), proc.stderr.read()
    assert proc.returncode == -signal.SIGKILL
    con = sqlite3.connect(db)
    try:
        seqs = [r[0] for r in con.execute("SELECT seq FROM frames ORDER BY id")]
        events = list(con.execute("SELECT action, alarm, node, rope FROM events"))
    finally:
        con.close()
    return seqs, events, int(line.split()[1])


def test_an_alarm_event_is_on_disk_when_add_event_returns(tmp_path):
    seqs, events, pending = _write_and_kill(tmp_path, "event")
    assert events == [("raise", "deviation:n1:r3", 1, 3)]
    assert seqs == [1] and pending == 0  # the frame pending before it went with it


@pytest.mark.parametrize("mode", ["flush", "next-frame"])
def test_a_pending_frame_is_on_disk_once_max_latency_has_passed(tmp_path, mode):
    seqs, events, pending = _write_and_kill(tmp_path, mode)
    assert seqs == ([1] if mode == "flush" else [1, 2]) and pending == 0
    assert events == []


def test_a_frame_still_pending_is_lost_to_the_kill(tmp_path):
    """The control: within the latency bound and the batch, the frame is not yet stored, so
    the tests above see the commits, not a kill that keeps everything."""
    seqs, events, pending = _write_and_kill(tmp_path, "pending")
    assert pending == 1 and seqs == [] and events == []
