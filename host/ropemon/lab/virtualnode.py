"""A virtual cage node: the MicroPython unix port on a pty, for mpremote without hardware.

Two pty pairs: `micropython` runs on the slave of pair A (its REPL is the
"node"), mpremote opens the slave of pair B (`VirtualNode.port`), and a thread
copies bytes between the two masters. The node's filesystem is the directory
it runs in.

A soft reset (Ctrl-D) ends the unix port; the virtual node then starts a new
one and puts it back in the raw REPL, as a board reboots, so mpremote works
as with a board: `mpremote connect PORT ...` soft-resets first, and
`mpremote connect PORT resume ...` keeps the interpreter's state.

Faults for tests: `kill()` is a power cut (the process dies, the line hangs
up), `break_after(n)` does the same after n more bytes from the host, in the
middle of whatever mpremote is sending.
"""
from __future__ import annotations

import os
import pty
import select
import signal
import subprocess
import sys
import threading
import tty
from pathlib import Path

from ropemon.firmware import micropython_command

_CHUNK = 4096


class VirtualNode:
    """The unix port of MicroPython behind a pty; `port` is what mpremote connects to."""

    def __init__(self, root: Path | str, micropython: str | None = None) -> None:
        self.root = Path(root)
        self.micropython = micropython or micropython_command()
        self.proc: subprocess.Popen[bytes] | None = None
        self.port = ""
        self.host_to_node_bytes = 0
        self.soft_resets = 0
        self._break_at: int | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._fds: dict[str, int] = {}
        self._lock = threading.Lock()

    def start(self) -> "VirtualNode":
        """Boot the node: start `micropython` in `root` and the byte copier."""
        self.root.mkdir(parents=True, exist_ok=True)
        host_master, host_slave = pty.openpty()
        tty.setraw(host_slave)  # raw from the first byte: a cooked pty would echo the node's output back
        # host_slave stays open here so the master never reads a hangup while
        # no mpremote is connected between two commands.
        self._fds = {"host": host_master, "host_slave": host_slave}
        self.port = os.ttyname(host_slave)
        self._spawn()
        self._stop.clear()
        self._thread = threading.Thread(target=self._copy, name="virtual-node-copier", daemon=True)
        self._thread.start()
        return self

    def _spawn(self) -> None:
        node_master, node_slave = pty.openpty()
        tty.setraw(node_slave)
        env = dict(os.environ)
        # Only the node's own directory is importable (no ~/.micropython/lib).
        env["MICROPYPATH"] = ""
        self.proc = subprocess.Popen(
            [self.micropython],
            stdin=node_slave, stdout=node_slave, stderr=node_slave,
            cwd=self.root, env=env, close_fds=True, start_new_session=True,
        )
        os.close(node_slave)
        self._fds["node"] = node_master

    def break_after(self, n_bytes: int) -> None:
        """Cut power once n_bytes more have gone from the host to the node."""
        with self._lock:
            self._break_at = self.host_to_node_bytes + n_bytes

    def kill(self) -> None:
        """Power cut: the micropython process dies and the line hangs up."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2)
        self._kill_process()
        self._close_fds()

    stop = kill

    def running(self) -> bool:
        """True until a power cut or kill (a soft reset's restart counts as running)."""
        return self._thread is not None and self._thread.is_alive() and not self._stop.is_set()

    def __enter__(self) -> "VirtualNode":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.kill()

    def _kill_process(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=5)

    def _close_fds(self) -> None:
        with self._lock:
            for fd in self._fds.values():
                try:
                    os.close(fd)
                except OSError:
                    pass
            self._fds = {}

    def _copy(self) -> None:
        host = self._fds["host"]
        while not self._stop.is_set():
            node = self._fds["node"]
            try:
                ready, _, _ = select.select([node, host], [], [], 0.05)
                if node in ready:
                    data = os.read(node, _CHUNK)  # EIO once the node process is gone
                    _write_all(host, data)
                if host in ready:
                    data = os.read(host, _CHUNK)
                    with self._lock:
                        limit = self._break_at
                        if limit is not None:
                            data = data[: max(0, limit - self.host_to_node_bytes)]
                        self.host_to_node_bytes += len(data)
                    _write_all(node, data)
                    if limit is not None and self.host_to_node_bytes >= limit:
                        self._power_cut_from_copier()
                        return
            except OSError:
                if self._soft_reset():
                    continue
                # The node died (crash, kill): hang up the host side too, as
                # the USB serial adapter of a dead board would.
                self._power_cut_from_copier()
                return

    def _soft_reset(self) -> bool:
        """A clean exit of the unix port is what Ctrl-D (soft reset) does to it; a
        board reboots instead and comes back in the raw REPL it was reset from.
        Emulate that, so mpremote works without `resume` too."""
        assert self.proc is not None
        try:
            code = self.proc.wait(timeout=1)
        except subprocess.TimeoutExpired:
            return False
        if code != 0 or self._stop.is_set():
            return False
        os.close(self._fds.pop("node"))
        self._spawn()
        self.soft_resets += 1
        _write_all(self._fds["host"], b"MPY: soft reboot\r\n")
        _write_all(self._fds["node"], b"\x01")  # back into the raw REPL, as a board stays in it
        return True

    def _power_cut_from_copier(self) -> None:
        self._stop.set()
        self._kill_process()
        self._close_fds()


def _write_all(fd: int, data: bytes) -> None:
    while data:
        n = os.write(fd, data)
        data = data[n:]
