"""`ropemon monitor` as a user runs it: two receiver ports (ptys read with pyserial),
a log, a deviation alarm; Ctrl-C ends it with everything committed."""
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

from ropemon.station.protocol import Rope, encode_frame
from ropemon.lab.vserial import VirtualPort

KEY = bytes(range(16))
ROOT = Path(__file__).resolve().parents[2]


def key_file(d: Path, key: bytes = KEY, name: str = "node1.key") -> Path:
    """A key file as the monitor takes it (--key-file NODE:PATH): the key in hex, mode 0600."""
    p = d / name
    p.write_text(key.hex() if isinstance(key, bytes) else key)
    p.chmod(0o600)
    return p


def wait_open(pid, paths, timeout_s=30.0):
    """Until process `pid` has every path open (pyserial flushes input on open)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        fds = Path(f"/proc/{pid}/fd")
        try:
            opened = {os.readlink(fd) for fd in fds.iterdir()}
        except OSError:
            opened = set()
        if set(paths) <= opened:
            time.sleep(0.1)           # open() returns after its input flush
            return
        time.sleep(0.05)
    raise AssertionError(f"monitor did not open {paths}")


def test_monitor_logs_frames_once_and_the_alarm(tmp_path):
    db = tmp_path / "hoist.db"
    with VirtualPort("pit") as a, VirtualPort("mid") as b:
        p = subprocess.Popen([sys.executable, "-m", "ropemon.cli", "monitor", "--port", f"pithead={a.port}",
                              "--port", f"mid-shaft={b.port}", "--db", str(db), "--key-file", f"1:{key_file(tmp_path)}",
                              "--refresh-hz", "20"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
        try:
            wait_open(p.pid, [a.port, b.port])
            for seq in range(40):
                w = encode_frame(node=1, seq=seq, time_ms=seq * 100, key=KEY, battery_mv=3900,
                                 ropes=[Rope(4600, 4600, 4600, 1300)] * 3 + [Rope(5600, 5600, 5600, 1500)])[1]
                a.write(w)
                if seq % 2:
                    b.write(w)                 # duplicates from the second receiver
                time.sleep(0.02)
            time.sleep(1.5)
        finally:
            p.send_signal(signal.SIGINT)
            out, err = p.communicate(timeout=20)
    assert p.returncode == 130, err
    assert "DEVIATION rope 4" in out and "frames 40  lost 0" in out
    con = sqlite3.connect(db)
    assert con.execute("SELECT count(*), count(DISTINCT seq) FROM frames").fetchone() == (40, 40)
    assert con.execute("SELECT action, kind, rope FROM events").fetchall() == [("raise", "deviation", 3)]
    assert con.execute("SELECT count(*) FROM link_stats WHERE receiver='mid-shaft'").fetchone()[0] >= 1


def test_monitor_accept_rewound_is_logged(tmp_path):
    db = tmp_path / "hoist.db"
    with VirtualPort("pit") as a:
        p = subprocess.Popen([sys.executable, "-m", "ropemon.cli", "monitor", "--port", f"pithead={a.port}",
                              "--db", str(db), "--key-file", f"1:{key_file(tmp_path)}", "--accept-rewound", "1"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                             env={**os.environ, "LOGNAME": "ropemon-test-operator", "USER": "ropemon-test-operator"})
        try:
            wait_open(p.pid, [a.port])
        finally:
            p.send_signal(signal.SIGINT)
            out, err = p.communicate(timeout=20)
    assert p.returncode == 130, err
    con = sqlite3.connect(db)
    rows = con.execute("SELECT action, kind, node, message FROM events").fetchall()
    assert [r[:3] for r in rows] == [("accept", "rewound", 1)]
    assert "operator ropemon-test-operator accepted node 1" in rows[0][3]
    r = subprocess.run([sys.executable, "-m", "ropemon.cli", "monitor", "--port", "loop://",
                        "--accept-rewound", "1"], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert r.returncode == 2 and "needs node keys" in r.stderr


def test_monitor_refuses_conflicting_keys_and_configs_of_different_hoists(tmp_path, capsys):
    """--key-file and --config are merged as in `ropemon decode`; contradictions are refused, not guessed."""
    import json

    from ropemon.cli import main
    from ropemon.commission.nodejson import example_physical, seal

    def node_json(name, node, key, area):
        p = tmp_path / name
        p.write_text(json.dumps(seal({"physical": dict(example_physical(), ropes=4, cylinder_area_m2=[area] * 4,
                                                       rated_rope_tension_N=80_000),
                                      "node": {"node_id": node, "key": list(key)}})))
        return str(p)

    a = node_json("a.json", 1, KEY, 0.0314)
    b = node_json("b.json", 2, bytes(range(1, 17)), 0.05)
    zeros = key_file(tmp_path, bytes(16), "zeros.key")
    assert main(["monitor", "--port", "loop://", "--config", a, "--key-file", f"1:{zeros}"]) == 2
    assert f"node 1: --key-file 1:{zeros}" in capsys.readouterr().err
    assert main(["monitor", "--port", "loop://", "--config", a, "--config", b]) == 2
    assert "describe different hoists" in capsys.readouterr().err
    assert main(["monitor", "--port", "loop://", "--key-file", f"1:{key_file(tmp_path, 'zz', 'zz.key')}"]) == 2
    assert "not hex" in capsys.readouterr().err


def test_headless_monitor_on_a_wrong_port_alarms_as_json_lines_and_stops_on_sigterm(tmp_path):
    """A wrong port and a node that is never heard: the headless station is not quiet. Within the
    configured seconds it prints RECEIVER DOWN (with the device) and SILENT for node 1 as JSON lines."""
    import json
    p = subprocess.Popen([sys.executable, "-m", "ropemon.cli", "monitor", "--port", "/dev/ttyUSB-ropemon-none",
                          "--key-file", f"1:{key_file(tmp_path)}", "--headless", "--silent-s", "1", "--db", str(tmp_path / "h.db")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    lines = []
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and {ln.get("id") for ln in lines} < {"receiver_down:pithead", "silent:n1"}:
            line = p.stdout.readline()
            if not line:
                break
            lines.append(json.loads(line))
    finally:
        p.send_signal(signal.SIGTERM)
        out, err = p.communicate(timeout=20)
    assert p.returncode == 0, err
    raised = {ln["id"]: ln for ln in lines if ln["event"] == "raise"}
    assert set(raised) >= {"receiver_down:pithead", "silent:n1"}, lines
    down = raised["receiver_down:pithead"]
    assert down["alarm"] == "receiver_down" and "/dev/ttyUSB-ropemon-none" in down["message"]
    assert down["t"].endswith("Z") and down["rope"] is None
    con = sqlite3.connect(tmp_path / "h.db")                  # and the log has them
    kinds = {r[0] for r in con.execute("SELECT kind FROM events WHERE action = 'raise'")}
    con.close()
    assert {"receiver_down", "silent"} <= kinds


def test_monitor_refuses_a_node_json_edited_after_ropemon_config(tmp_path):
    """The station trusts `physical` (areas, thresholds) only as `ropemon config` wrote it."""
    import json

    from ropemon.firmware import FIRMWARE_DIR

    doc = json.loads((FIRMWARE_DIR / "node.json").read_text())
    doc["physical"]["imbalance_frac"] = 0.3   # a looser deviation alarm, by hand
    edited = tmp_path / "node.json"
    edited.write_text(json.dumps(doc, indent=1))
    # a monitor that took the file would run until stopped: the timeout fails the test then
    r = subprocess.run([sys.executable, "-m", "ropemon.cli", "monitor", "--port", "loop://", "--headless",
                        "--config", str(edited)], capture_output=True, text=True, cwd=ROOT, timeout=30)
    assert r.returncode == 2, r.stderr
    assert f"ropemon monitor: {edited}: changed after `ropemon config` wrote it" in r.stderr
    assert "rebuild it with `ropemon config`" in r.stderr
