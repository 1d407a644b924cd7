"""A station with its web face, fed by simulated winds: the rig of tests/web and `ropemon bench web`.

`WebStation(folder, hoists=N)` writes what an installed station has (one node.json per
hoist with its own key, station.toml with a [web] table on a free localhost port, a users
file made with `ropemon.station.users.add_user`), opens one pty pair per hoist as its
receiver (`lab.vserial.VirtualPort`: the station opens the pty as it would open an RS485
adapter), and runs `ropemon serve station.toml` as a subprocess (or, with `server`, another
command on the same ptys: the web benchmark's baseline). A feeder thread writes each
hoist's next frame every 1/frame_hz s and remembers when it was written (`sent`): that moment
is the frame's arrival at the station.

`Wind` is one hoist's simulated wind: the cage from the bottom to the pithead and back, an
accelerate/cruise/decelerate speed profile, every rope's tension the hanging load shared
four ways, the rope below the sheave and the acceleration added, a small per-rope offset and
noise; `deviate(rope, frac)` forces one rope off the mean (a deviation alarm).
"""
from __future__ import annotations

import json
import math
import os
import random
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ropemon.lab.localnet import free_port  # noqa: F401  (the web tests' ports too)
from ropemon.station.protocol import DAN_TO_N, encode_frame

G = 9.81


def physical() -> dict:
    """The example site's physical section with a tenth of its seal friction: each rope's band
    (DEVIATION POSSIBLE) stays well inside the 10 % limit at rest, so the alarms a test sees
    are the ones it forces."""
    from ropemon.commission.nodejson import example_physical

    p = example_physical()
    for k in ("Fs", "Fc"):
        p["friction"][k] = {n: v / 10 for n, v in p["friction"][k].items()}
    return p


@dataclass
class Sent:
    """One frame written to the station: when (time.time()), its seq and rope tensions in daN."""

    t: float
    seq: int
    dan: tuple[int, ...]
    depth_mm: int
    speed_mm_s: int


class Wind:
    """One hoist's simulated wind (module docstring); `frame(t_s)` -> (seq, daN per rope, wire)."""

    def __init__(self, node: int, key: bytes, seed: int = 1, ropes: int = 4, shaft_m: float = 806.0,
                 v_max: float = 10.0, accel: float = 0.8, rest_s: float = 8.0, cage_n: float = 185_400.0,
                 payload_n: float = 78_000.0, rope_n_per_m: float = 20.0, frame_hz: float = 10.0) -> None:
        self.node, self.key, self.ropes = node, key, ropes
        self.shaft_m, self.v_max, self.accel, self.rest_s = shaft_m, v_max, accel, rest_s
        self.cage_n, self.payload_n, self.rope_n_per_m = cage_n, payload_n, rope_n_per_m
        self.frame_hz = frame_hz
        self.rng = random.Random(seed)
        self.offsets = [1.0 + self.rng.uniform(-0.015, 0.015) for _ in range(ropes)]
        self.forced: dict[int, float] = {}          # rope (from 0) -> fraction added
        self.seq = (1 << 16) * 3 + self.rng.randint(0, 1000)   # boot 3 (seq's high half), count
        t_ramp = v_max / accel
        d_ramp = 0.5 * accel * t_ramp ** 2
        self.t_trip = 2 * t_ramp + (shaft_m - 2 * d_ramp) / v_max
        self.t_ramp, self.d_ramp = t_ramp, d_ramp

    def adjust(self, seq: int, dan: list[int]) -> list[int]:
        """The ropes' tensions (daN) of frame `seq` as sent: a subclass may mark them."""
        return dan

    def deviate(self, rope: int, frac: float) -> None:
        """Rope `rope` (from 0) reads `frac` above (or below) its share from the next frame on; 0 ends it."""
        if frac:
            self.forced[rope] = frac
        else:
            self.forced.pop(rope, None)

    def kinematics(self, t_s: float) -> tuple[float, float, float]:
        """Depth (m below the pithead), speed (m/s, + up), acceleration (m/s^2, + up) at `t_s`."""
        cycle = 2 * (self.rest_s + self.t_trip)
        t = t_s % cycle
        up = t < self.rest_s + self.t_trip
        t = t if up else t - self.rest_s - self.t_trip
        if t < self.rest_s:
            return (self.shaft_m if up else 0.0), 0.0, 0.0
        t -= self.rest_s
        if t < self.t_ramp:
            s, v, a = 0.5 * self.accel * t * t, self.accel * t, self.accel
        elif t < self.t_trip - self.t_ramp:
            s, v, a = self.d_ramp + self.v_max * (t - self.t_ramp), self.v_max, 0.0
        else:
            r = self.t_trip - t
            s, v, a = self.shaft_m - 0.5 * self.accel * r * r, self.accel * r, -self.accel
        if up:       # loaded, from the bottom up
            return self.shaft_m - s, v, a
        return s, -v, -a

    def frame(self, t_s: float) -> tuple[int, tuple[int, ...], int, int, bytes]:
        """The next frame at wind time `t_s`: (seq, daN per rope, depth mm, speed mm/s, wire bytes)."""
        depth, v, a = self.kinematics(t_s)
        loaded = v > 0 or (v == 0 and depth > self.shaft_m / 2)
        hanging = self.cage_n + (self.payload_n if loaded else 0.0) + self.ropes * self.rope_n_per_m * depth
        share = hanging * (1 + a / G) / self.ropes
        newtons = [share * self.offsets[i] * (1 + self.forced.get(i, 0.0)) + self.rng.gauss(0.0, 60.0)
                   for i in range(self.ropes)]
        dan = self.adjust(self.seq + 1, [int(round(n / DAN_TO_N)) for n in newtons])
        ropes = []
        for d in dan:
            kpa = int(round(d * DAN_TO_N * 1.16 / 7.854e-3 / 1000))     # the raw pressure: the seal holds ~16 % back
            ropes.append((d, d - self.rng.randint(5, 40), d + self.rng.randint(5, 40), min(kpa, 65_000)))
        self.seq += 1
        depth_mm, speed_mm_s = int(round(depth * 1000)), int(round(v * 1000))
        _, wire = encode_frame(node=self.node, seq=self.seq, time_ms=int(t_s * 1000) & 0xFFFFFFFF, ropes=ropes,
                               depth_mm=depth_mm, speed_mm_s=speed_mm_s, battery_mv=12_400, key=self.key)
        return self.seq, tuple(dan), depth_mm, speed_mm_s, wire


@dataclass
class HoistRig:
    id: str
    wind: Wind
    port: object                     # VirtualPort
    sent: dict[int, Sent] = field(default_factory=dict)
    paused: bool = False


class WebStation:
    """A `ropemon serve` subprocess with a [web] face, fed by one `Wind` per hoist (module docstring)."""

    def __init__(self, folder: Path, hoists: int = 1, users: dict[str, tuple[str, str]] | None = None,
                 frame_hz: float = 10.0, tick_hz: float | None = None, silent_s: float = 3.0,
                 view_without_login: bool = True, data_dir: bool = True, seed: int = 1,
                 extra_station: str = "", wind: dict | None = None, wind_class: type | None = None,
                 server: Callable[["WebStation"], list[str]] | None = None) -> None:
        from ropemon.lab.vserial import VirtualPort

        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.frame_hz = frame_hz
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.rigs: dict[str, HoistRig] = {}
        self.proc: subprocess.Popen | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self.t0 = time.monotonic()
        ids = ["north", "south", "east", "west", "main", "aux", "service", "rock"]
        ids += [f"hoist-{i}" for i in range(len(ids), hoists)]
        lines = ["[station]", 'name = "Test shaft"', f"silent_s = {silent_s}"]
        if tick_hz is not None:
            lines.append(f"tick_hz = {tick_hz}")
        if data_dir:
            lines.append('data_dir = "data"')
        from ropemon.commission.nodejson import make_node_json
        for i in range(hoists):
            hid = ids[i]
            key = random.Random(seed * 1000 + i).randbytes(16)
            cfg = self.folder / f"{hid}-node.json"
            cfg.write_text(json.dumps(make_node_json(physical(), node_id=1, key=key)))
            os.chmod(cfg, 0o600)
            vp = VirtualPort(hid)
            self.rigs[hid] = HoistRig(hid, (wind_class or Wind)(1, key, seed=seed * 100 + i, frame_hz=frame_hz, **(wind or {})), vp)
            lines += ["", "[[hoist]]", f'id = "{hid}"', f'name = "{hid.capitalize()} shaft"',
                      f'configs = ["{cfg.name}"]', f'receivers = {{ pithead = "{vp.port}" }}']
        lines += ["", "[web]", 'bind = "127.0.0.1"', f"port = {self.port}",
                  f"view_without_login = {'true' if view_without_login else 'false'}"]
        self.users_path: Path | None = None
        if users:
            from ropemon.station.users import add_user
            self.users_path = self.folder / "users.toml"
            for name, (role, password) in users.items():
                add_user(self.users_path, name, role, password)
            lines.append('users = "users.toml"')
        self.station_toml = self.folder / "station.toml"
        self.station_toml.write_text("\n".join(lines) + "\n" + extra_station)
        self.log = open(self.folder / "serve.log", "w+b")
        self.server = server

    # -- the station process -------------------------------------------------------------

    def start(self, timeout_s: float = 20.0) -> "WebStation":
        """Start `ropemon serve` and the feeder; return once the web face answers."""
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        cmd = self.server(self) if self.server is not None else \
            [sys.executable, "-m", "ropemon.cli", "serve", str(self.station_toml)]
        self.proc = subprocess.Popen(cmd, stdout=self.log, stderr=subprocess.STDOUT, env=env, cwd=self.folder)
        self._thread = threading.Thread(target=self._feed, name="wind feeder", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + timeout_s
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"ropemon serve exited {self.proc.returncode}:\n{self.output()}")
            try:
                with urllib.request.urlopen(self.url + "/", timeout=2) as r:
                    if r.status < 500:
                        break
            except OSError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError(f"ropemon serve: no web face at {self.url} in {timeout_s} s:\n{self.output()}")
            time.sleep(0.1)
        return self

    def output(self) -> str:
        """What `ropemon serve` printed so far (stdout and stderr)."""
        if not self.log.closed:
            self.log.flush()
        return (self.folder / "serve.log").read_bytes().decode(errors="replace")

    def events(self) -> list[dict]:
        """The alarm events `ropemon serve` printed so far (its JSON lines)."""
        out = []
        for line in self.output().splitlines():
            if line.startswith("{"):
                try:
                    out.append(json.loads(line))
                except ValueError:
                    pass
        return out

    def kill(self) -> None:
        """SIGKILL the station (as a crash or a power cut would); the feeder stops writing."""
        self.pause_all()
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)

    def cpu_s(self) -> float:
        """The station process's CPU time so far (user + system, from /proc/PID/stat)."""
        assert self.proc is not None
        with open(f"/proc/{self.proc.pid}/stat") as f:
            parts = f.read().rsplit(")", 1)[1].split()
        return (int(parts[11]) + int(parts[12])) / os.sysconf("SC_CLK_TCK")

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        for rig in self.rigs.values():
            rig.port.close()   # type: ignore[attr-defined]
        self.log.close()

    def __enter__(self) -> "WebStation":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- the winds -------------------------------------------------------------------------

    def pause_all(self) -> None:
        with self._lock:
            for rig in self.rigs.values():
                rig.paused = True

    def deviate(self, hoist: str, rope: int, frac: float) -> float:
        """Force `rope` (from 0) of `hoist` off by `frac` from the next frame; returns time.time() then."""
        with self._lock:
            self.rigs[hoist].wind.deviate(rope, frac)
            return time.time()

    def last(self, hoist: str) -> Sent | None:
        with self._lock:
            sent = self.rigs[hoist].sent
            return sent[max(sent)] if sent else None

    def resume_all(self) -> None:
        with self._lock:
            for rig in self.rigs.values():
                rig.paused = False

    def sent(self, hoist: str) -> dict[int, Sent]:
        with self._lock:
            return dict(self.rigs[hoist].sent)

    def _feed(self) -> None:
        period = 1.0 / self.frame_hz
        k = 0
        start = time.monotonic()
        rigs = list(self.rigs.values())
        while not self._stop.is_set():
            k += 1
            for i, rig in enumerate(rigs):
                # the hoists' frames spread over the period, as nodes that are not in step
                target = start + (k + i / len(rigs)) * period
                delay = target - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    return
                with self._lock:
                    if rig.paused:
                        continue
                    seq, dan, depth, speed, wire = rig.wind.frame(time.monotonic() - self.t0)
                try:
                    rig.port.write(wire, timeout_s=0.5)   # type: ignore[attr-defined]
                except (OSError, TimeoutError):
                    continue
                t = time.time()
                with self._lock:
                    rig.sent[seq] = Sent(t, seq, dan, depth, speed)
                    if len(rig.sent) > 20_000:
                        for old in sorted(rig.sent)[:5_000]:
                            del rig.sent[old]


def kn(dan: int) -> float:
    """daN -> kN as the page rounds them (2 decimals)."""
    return round(dan * DAN_TO_N / 1000, 2)


def seconds(x: float) -> str:
    return f"{x:.3f}" if math.isfinite(x) else "-"
