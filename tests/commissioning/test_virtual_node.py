"""The virtual node: the real mpremote reaches the MicroPython unix port through the pty pair."""
from __future__ import annotations

import hashlib
import subprocess
import sys

import pytest

from ropemon.lab.virtualnode import VirtualNode


def mpremote(port: str, *args: str, timeout: float = 20) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mpremote", "connect", port, "resume", *args],
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def node(tmp_path):
    with VirtualNode(tmp_path / "node") as n:
        yield n


def test_mpremote_runs_code_on_the_unix_port(node):
    r = mpremote(node.port, "exec", "import sys, os; print(sys.implementation.name, sys.platform, os.getcwd())")
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["micropython", "linux", str(node.root)]


def test_the_node_filesystem_is_its_directory(node, tmp_path):
    src = tmp_path / "blob.bin"
    data = bytes(range(256)) * 40  # every byte value, over several raw-paste windows
    src.write_bytes(data)
    r = mpremote(node.port, "fs", "mkdir", ":d", "+", "fs", "cp", str(src), ":d/blob.bin",
                 "+", "fs", "sha256sum", ":d/blob.bin")
    assert r.returncode == 0, r.stderr
    assert (node.root / "d" / "blob.bin").read_bytes() == data
    assert hashlib.sha256(data).hexdigest() in r.stdout


def test_state_survives_between_mpremote_runs_with_resume(node):
    assert mpremote(node.port, "exec", "x = 41").returncode == 0
    r = mpremote(node.port, "exec", "print(x + 1)")
    assert r.stdout.strip() == "42"


def test_kill_is_a_power_cut(node):
    assert mpremote(node.port, "exec", "pass").returncode == 0
    node.kill()
    assert not node.running()
    r = mpremote(node.port, "exec", "pass", timeout=10)
    assert r.returncode != 0


def test_break_after_cuts_the_link_after_exactly_n_bytes(node, tmp_path):
    assert mpremote(node.port, "exec", "pass").returncode == 0
    sent = node.host_to_node_bytes
    node.break_after(300)
    src = tmp_path / "big.bin"
    src.write_bytes(b"x" * 5000)
    r = mpremote(node.port, "fs", "cp", str(src), ":big.bin", timeout=10)
    assert r.returncode != 0
    assert node.host_to_node_bytes == sent + 300
    assert not node.running()
    # Whatever reached the file before the cut is a fraction of it, not the file.
    partial = node.root / "big.bin"
    assert not partial.exists() or partial.stat().st_size < 5000


def test_the_virtual_node_tool(tmp_path):
    """tools/virtual_node.py prints its port and serves mpremote until SIGTERM."""
    from pathlib import Path
    tool = Path(__file__).resolve().parents[2] / "tools" / "virtual_node.py"
    proc = subprocess.Popen([sys.executable, str(tool), "--root", str(tmp_path / "n")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = proc.stdout.readline()
        assert first.startswith("virtual node: port /dev/"), first + proc.stderr.read()
        port = first.split()[3].rstrip(",")
        r = mpremote(port, "exec", "open('hello.txt', 'w').write('hi')")
        assert r.returncode == 0, r.stderr
        assert (tmp_path / "n" / "hello.txt").read_text() == "hi"
    finally:
        proc.terminate()
        assert proc.wait(timeout=10) == 0


def test_a_soft_reset_reboots_the_node_as_a_board_does(node):
    """Without `resume` mpremote soft-resets first: the node restarts, state is gone, files stay."""
    assert mpremote(node.port, "exec", "x = 1; open('kept.txt', 'w').write('k')").returncode == 0
    r = subprocess.run([sys.executable, "-m", "mpremote", "connect", node.port,
                        "exec", "print('x' in globals(), open('kept.txt').read())"],
                       capture_output=True, text=True, timeout=20)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["False", "k"]
    assert node.soft_resets == 1 and node.running()
