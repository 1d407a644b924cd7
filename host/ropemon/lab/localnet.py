"""Local network helpers for the tests and benchmarks: a free localhost port, and Debian's
Mosquitto on one (a temporary config; start, SIGKILL and restart on the same port, with its
sessions saved every second, as a site's broker would)."""
from __future__ import annotations

import getpass
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
MOSQUITTO_PASSWD = shutil.which("mosquitto_passwd") or "/usr/bin/mosquitto_passwd"


def free_port(preferred: int = 0) -> int:
    """A TCP port free on 127.0.0.1 now: `preferred` if it is, else one the system picks."""
    for port in dict.fromkeys((preferred, 0)):
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return int(s.getsockname()[1])
    raise OSError("no free port on 127.0.0.1")


def available() -> bool:
    """Whether Mosquitto is installed."""
    return Path(MOSQUITTO).exists()


class Broker:
    """Mosquitto on a free localhost port, its config and sessions in `tmp`/mosquitto (a new
    temporary folder when `tmp` is None, removed by `close`).

    `users` ({name: password}): only they may connect (a password file made with
    mosquitto_passwd; anonymous clients refused). `tls` (CA, server certificate, server key
    files, PEM): the port is a TLS listener."""

    def __init__(self, tmp: Path | None = None, *, users: dict[str, str] | None = None,
                 tls: tuple[Path, Path, Path] | None = None) -> None:
        if not available():
            raise RuntimeError("Mosquitto is missing: apt-get install mosquitto (make test installs it)")
        self._own = tmp is None
        base = Path(tempfile.mkdtemp(prefix="ropemon-broker-")) if tmp is None else tmp
        self.dir = base / "mosquitto"
        self.dir.mkdir(exist_ok=True)
        self.port = free_port()
        self.conf = self.dir / "mosquitto.conf"
        access = "allow_anonymous true\n"
        if users is not None:
            if not Path(MOSQUITTO_PASSWD).exists():
                raise RuntimeError(f"{MOSQUITTO_PASSWD} is missing (Debian's mosquitto package has it)")
            pw = self.dir / "passwords"
            pw.write_text("")
            for name, password in users.items():
                subprocess.run([MOSQUITTO_PASSWD, "-b", str(pw), name, password], check=True,
                               capture_output=True)
            access = f"allow_anonymous false\npassword_file {pw}\n"
        if tls is not None:
            ca, cert, key = tls
            access += f"cafile {ca}\ncertfile {cert}\nkeyfile {key}\n"
        self.conf.write_text(
            f"listener {self.port} 127.0.0.1\n{access}"
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
        """How many times the broker has begun saving its sessions to disk (its log's count; the
        line is written before the save, which a SIGKILL can still cut short: see `saved`)."""
        log = self.dir / "mosquitto.log"
        return log.read_text(errors="replace").count("Saving in-memory database") if log.exists() else 0

    def saved(self) -> tuple[int, int, int] | None:
        """The sessions file of the broker's last completed save, (inode, mtime ns, size); None
        before the first. Mosquitto writes mosquitto.db.new and renames it over mosquitto.db, so
        a value that changed means a save has finished since, and a restart will load it."""
        try:
            st = (self.dir / "mosquitto.db").stat()
        except FileNotFoundError:
            return None
        return (st.st_ino, st.st_mtime_ns, st.st_size)

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
        if self._own:
            shutil.rmtree(self.dir.parent, ignore_errors=True)
