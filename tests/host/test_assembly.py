"""One assembly: every entry point builds its hoist's station through `assembly.build_hoist`,
and a station on an injected clock stamps everything it writes on that clock."""
from __future__ import annotations

import argparse
import json
import sqlite3
from pathlib import Path

import pytest

from ropemon.commission.nodejson import example_physical, make_node_json
from ropemon.station import assembly
from ropemon.station.assembly import HoistSpec, build_hoist, run_loop
from ropemon.station.pipeline import AcceptRewound, Listener
from ropemon.station.protocol import Rope, encode_frame
from ropemon.station.nodefigures import NodeFigures

KEY = bytes(range(16))
HOST = Path(__file__).resolve().parents[2] / "host" / "ropemon"


def node_json(tmp_path: Path, name: str = "node.json", node: int = 1, key: bytes = KEY) -> Path:
    p = tmp_path / name
    p.write_text(json.dumps(make_node_json(example_physical(), node_id=node, key=key)))
    return p


def wire(seq: int, time_ms: int) -> bytes:
    return encode_frame(node=1, seq=seq, time_ms=time_ms, key=KEY, battery_mv=12_000,
                        ropes=[Rope(4600, 4600, 4600, 1300)] * 4)[1]


class Built(Exception):
    """Raised by the spy to stop an entry point once its station is built."""


@pytest.fixture
def built(monkeypatch):
    """Every call of `assembly.build_hoist`: (spec, clock, kw); the real one runs unless `stop`."""
    calls: list = []
    real = assembly.build_hoist
    stop = {"now": False}

    def spy(spec, clock, **kw):
        calls.append((spec, clock, kw))
        if stop["now"]:
            raise Built
        return real(spec, clock, **kw)

    monkeypatch.setattr(assembly, "build_hoist", spy)
    return calls, stop


def test_serve_builds_each_hoist_through_build_hoist(tmp_path, built):
    from ropemon.station.hoists import Station
    from ropemon.station.stationfile import load_station_file

    calls, _ = built
    node_json(tmp_path, "north.json")
    node_json(tmp_path, "south.json", key=bytes(range(1, 17)))
    (tmp_path / "station.toml").write_text(
        '[station]\ndata_dir = "data"\n\n[[hoist]]\nid = "north"\nconfigs = ["north.json"]\n'
        'receivers = { pithead = "loop://" }\n\n[[hoist]]\nid = "south"\nconfigs = ["south.json"]\n'
        'receivers = { pithead = "loop://" }\n')
    s = Station(load_station_file(tmp_path / "station.toml"))
    try:
        assert [c[0].id for c in calls] == ["north", "south"]
        spec, _, kw = calls[0]
        assert spec.keys == {1: KEY} and spec.settings.nodes == (1,) and spec.receivers == (("pithead", "loop://"),)
        assert kw["store"] is s.hoists["north"].store and kw["wake"] is s._wake
        assert s.hoists["north"].pipeline.hub.wake is s._wake          # given by constructor, not set from outside
    finally:
        s.close()


def test_monitor_builds_its_one_hoist_from_the_command_line(tmp_path, built):
    from ropemon.station import monitor

    calls, stop = built
    stop["now"] = True
    p = argparse.ArgumentParser()
    monitor.add_arguments(p)
    args = p.parse_args(["--port", "pithead=loop://", "--port", "loop://", "--config", str(node_json(tmp_path)),
                         "--headless", "--silent-s", "7", "--baud", "9600"])
    with pytest.raises(Built):
        monitor.run(args)
    (spec, clock, kw), = calls
    assert spec.receivers == (("pithead", "loop://"), ("mid-shaft", "loop://")) and spec.baud == 9600
    assert spec.keys == {1: KEY} and spec.settings.silent_s == 7 and spec.settings.nodes == (1,)
    assert [type(v).__name__ for v in kw["views"]] == ["JsonAlarmLines"]


def test_replay_builds_through_build_hoist_and_stamps_everything_on_node_time(tmp_path, built):
    from ropemon.commission.replay import replay_to_store

    calls, _ = built
    frames = tmp_path / "frames.bin"
    times = [100_000 + 100 * k for k in range(20)] + [130_000 + 100 * k for k in range(20)]   # a 28 s gap
    frames.write_bytes(b"".join(wire(seq, t) for seq, t in enumerate(times)))
    db = tmp_path / "replay.db"
    fig = replay_to_store(frames, node_json(tmp_path), db)
    (spec, clock, kw), = calls
    assert kw["wall"] is clock and fig["frames"] == 40
    assert fig["alarms"]["silent"] == {"raise": 1, "clear": 1}
    con = sqlite3.connect(db)
    node_time = (100.0, 132.0)
    for table, col in (("events", "time_s"), ("link_stats", "time_s"), ("frames", "rx_time")):
        lo, hi, n = con.execute(f"SELECT min({col}), max({col}), count(*) FROM {table}").fetchone()
        assert n and node_time[0] <= lo <= hi <= node_time[1], (table, lo, hi)


def test_the_demo_builds_its_station_through_build_hoist(built):
    from ropemon.lab.demo import DemoClock, demo_host

    calls, _ = built
    clock = DemoClock(10.0, start_s=1000.0)
    host = demo_host({1: KEY}, None, clock)
    (spec, got_clock, kw), = calls
    assert got_clock is clock and kw["wall"] is clock and host.pipeline.hub.clock is clock
    assert [type(v).__name__ for v in kw["views"]] == ["FrameKeeper"]


def test_no_entry_point_wires_a_station_itself():
    """The listeners and the HoistPipeline are made in assembly.py only (tests aside)."""
    for rel in ("station/monitor.py", "station/hoists.py", "commission/replay.py", "lab/demo.py",
                "lab/demo_station.py"):
        text = (HOST / rel).read_text()
        for made in ("HoistPipeline(", "AlarmListener(", "StoreListener(", "station_listeners(", ".hub.clock =",
                     ".hub.wake ="):
            assert made not in text, (rel, made)


class Failing(Listener):
    name = "failing"

    def on_frame(self, item, now_s):
        raise RuntimeError("boom")


def test_a_station_on_an_injected_clock_stamps_its_own_events_and_rx_times_on_it():
    t = [500.0]
    hoist = build_hoist(HoistSpec("x", NodeFigures(), {1: KEY}), lambda: t[0], wall=lambda: t[0] + 0.5,
                        views=[Failing()])
    s = hoist.pipeline
    seen = []
    s.add(type("Events", (Listener,), {"on_event": lambda self, e: seen.append(e)})())
    s.feed("pithead", wire(1, 1000))
    s.submit(AcceptRewound("tester", "test", node=1))
    s.pump()
    s.close()
    assert {e.action for e in seen} >= {"error", "accept"}
    assert all(e.time_s == 500.5 for e in seen if e.action in ("error", "accept"))
    assert "1970-01-01 00:08:20 UTC" in next(e.message for e in seen if e.action == "accept")


def test_run_loop_ticks_on_its_period_and_pumps_when_woken():
    import threading

    class Counting:
        def __init__(self):
            self.pumps = self.ticks = 0

        def pump(self):
            self.pumps += 1

        def tick(self):
            self.ticks += 1

    s, wake, woken = Counting(), threading.Event(), []

    def wait(timeout):
        woken.append(timeout)
        return None

    run_loop([s], 10.0, lambda: len(woken) >= 3, wake=wake, wait=wait)
    assert s.ticks == 1 and s.pumps == 3           # one tick at the start, then pumps only (10 s period)
    s2, keys = Counting(), iter([True, None, None])
    run_loop([s2], 10.0, lambda: s2.pumps >= 3, wait=lambda timeout: next(keys), first_tick_s=10.0)
    assert s2.ticks == 1                           # none at the start; one at once after a "key"
