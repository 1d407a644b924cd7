"""Mosquitto (Debian's package, installed by `make test`) on a free localhost port with a
temporary config, for the MQTT tests: start, kill (SIGKILL) and restart on the same port.
Sessions persist across a restart (autosave every second), as a site's broker would."""
from __future__ import annotations

import getpass
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

from scada_rig import free_port

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"


def available() -> bool:
    return Path(MOSQUITTO).exists()


class Broker:
    def __init__(self, tmp: Path) -> None:
        self.dir = tmp / "mosquitto"
        self.dir.mkdir(exist_ok=True)
        self.port = free_port()
        self.conf = self.dir / "mosquitto.conf"
        self.conf.write_text(
            f"listener {self.port} 127.0.0.1\nallow_anonymous true\n"
            f"persistence true\npersistence_location {self.dir}/\nautosave_interval 1\n"
            "max_queued_messages 0\nmax_inflight_messages 0\n"
            # started as root, mosquitto switches to this user: keep the one that owns the temp dir
            f"user {getpass.getuser()}\n"
            f"log_dest file {self.dir}/mosquitto.log\n")
        self.proc: subprocess.Popen | None = None
        self.start()

    def start(self) -> None:
        self.proc = subprocess.Popen([MOSQUITTO, "-c", str(self.conf)], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)
        end = time.monotonic() + 10
        while time.monotonic() < end:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                return
            except OSError:
                if self.proc.poll() is not None:
                    raise RuntimeError(f"mosquitto exited: {(self.dir / 'mosquitto.log').read_text()[-2000:]}")
                time.sleep(0.05)
        raise RuntimeError("mosquitto did not listen within 10 s")

    def saves(self) -> int:
        """How many times the broker has saved its sessions to disk (its log's count)."""
        log = self.dir / "mosquitto.log"
        return log.read_text(errors="replace").count("Saving in-memory database") if log.exists() else 0

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)
        self.proc = None

    def restart(self) -> None:
        self.kill()
        self.start()

    def close(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        self.proc = None
