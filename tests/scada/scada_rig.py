"""A station of N hoists fed by hand, for the SCADA faces' tests and benchmarks.

Each hoist has one node (id 1, its own key); `feed` hands one frame to a hoist's station
and `step` pumps and ticks every hoist. The clock is the test's (`rig.now`), so alarm
timing (NODE SILENT after silent_s) is exact.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

from ropemon.lab.localnet import free_port  # noqa: F401  (the SCADA tests' ports)
from ropemon.commission.nodejson import example_physical, make_node_json
from ropemon.station.hoists import Station
from ropemon.station.protocol import encode_frame
from ropemon.station.stationfile import load_station_file


def key_of(i: int) -> bytes:
    return bytes((i * 7 + k) & 0xFF for k in range(16))


def write_station(tmp: Path, n_hoists: int, faces: str = "", data_dir: bool = True) -> Path:
    lines = ['[station]', 'name = "test shaft"', 'silent_s = 2.0']
    if data_dir:
        lines.append('data_dir = "data"')
    for i in range(n_hoists):
        name = f"h{i}.json"
        (tmp / name).write_text(json.dumps(make_node_json(example_physical(), node_id=1, key=key_of(i))))
        lines += ["", "[[hoist]]", f'id = "h{i}"', f'configs = ["{name}"]', 'receivers = { pithead = "loop://" }']
    p = tmp / "station.toml"
    p.write_text("\n".join(lines) + "\n\n" + faces)
    return p


class Rig:
    def __init__(self, tmp: Path, n_hoists: int, faces: str = "", data_dir: bool = True, now: float = 1_000.0):
        self.now = now
        self.file = load_station_file(write_station(tmp, n_hoists, faces, data_dir))
        self.stations = Station(self.file, clock=lambda: self.now)
        self.seq = {h: 0 for h in self.stations.hoists}
        self.ids = list(self.stations.hoists)

    def feed(self, hoist: str, tensions=(5000, 5100, 4900, 5000), positions=None, **kw) -> int:
        """One frame of hoist's node 1; returns its seq. `positions`: each rope's pos_01mm
        (None: absent); without them the frame's ropes carry no position. `version`,
        `stroke_mask` and the frame's other fields go in `kw`."""
        self.seq[hoist] += 1
        i = self.ids.index(hoist)
        ropes = [(t, t - 50, t + 50, 8000) if t is not None else (-32768, -32768, -32768, 0xFFFF) for t in tensions]
        if positions is not None:
            ropes = [r + (-32768 if x is None else x,) for r, x in zip(ropes, positions)]
        kw.setdefault("battery_mv", 12_000)
        kw.setdefault("time_ms", self.seq[hoist] * 100)
        wire = encode_frame(node=1, seq=self.seq[hoist], key=key_of(i), ropes=ropes, **kw)[1]
        self.stations.hoists[hoist].pipeline.feed("pithead", wire)
        return self.seq[hoist]

    def step(self, dt: float = 0.25) -> None:
        self.now += dt
        self.stations.step()

    def close(self) -> None:
        self.stations.close()


def wait(cond, timeout=20.0, what="condition"):
    """Poll `cond` until true; fail naming `what` after `timeout` s."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")
