"""One hoist's pipeline, built one way, and the one loop that runs pipelines.

`HoistSpec` is what a hoist's pipeline is built from: its figures, node keys, alarm settings
and receivers. `spec_from_config` makes one from a station file's hoist (`ropemon serve`,
through `Station`); `ropemon monitor` makes one from its command line, `ropemon replay
--db` and the demo from a node.json. `build_hoist(spec, clock)` builds the `HoistPipeline`
with its hub, keys and listeners (alarm engine, the log when given, then the views), its
replay protection resumed from the log, and returns it as a `Hoist`.

`run_loop` pumps pipelines and ticks them on a period until told to stop: `Station.run`
(`ropemon serve`, the demo through a station file), `ropemon monitor` with its screen
(`monitor.live_loop`) or headless, and the demo's own pipeline run on it.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from ropemon.station.alarms import AlarmSettings
from ropemon.station.link import DEFAULT_BAUDRATE
from ropemon.station.pipeline import AlarmListener, Listener, HoistPipeline, station_listeners
from ropemon.station.protocol import load_node_keys
from ropemon.station.nodefigures import NodeFigures, alarm_settings, figures_from_configs
from ropemon.station.stationfile import HoistConfig


@dataclass(frozen=True)
class HoistSpec:
    """What one hoist's pipeline is built from."""

    id: str
    figures: NodeFigures
    keys: dict[int, bytes]                      # node -> key; empty: frames are not authenticated
    settings: AlarmSettings | None = None
    receivers: tuple[tuple[str, str], ...] = ()  # (name, pyserial URL), opened by `Hoist.start`
    baud: int = DEFAULT_BAUDRATE
    rs485: bool = False
    accept_rewound: tuple[int, ...] = ()        # nodes whose next authenticated frame is a new baseline
    name: str = ""
    config: HoistConfig | None = field(default=None, compare=False)   # the station file's hoist, if any


@dataclass
class Hoist:
    """One hoist as built: its figures, its pipeline and the listeners it was built with."""

    id: str
    name: str
    figures: NodeFigures
    keys: dict[int, bytes]
    pipeline: HoistPipeline
    alarms: AlarmListener
    store: Any = None                 # ropemon.station.store.Store, or None without a log
    db_path: Path | None = None
    config: HoistConfig | None = None   # the station file's hoist (its receivers, configs), if any
    spec: HoistSpec | None = None       # what it was built from

    def start(self) -> None:
        """Open the spec's receiver ports (each in its own reader thread)."""
        spec = self.spec
        if spec is None:
            return
        for name, url in spec.receivers:
            self.pipeline.add_port(url, name, baudrate=spec.baud, rs485=spec.rs485).start()


def spec_from_config(h: HoistConfig, silent_s: float) -> HoistSpec:
    """A station file's hoist as a spec: figures and keys from its node configs (configs that
    disagree on a node's key are refused), every configured node silent until heard.
    ValueError names the hoist."""
    try:
        figures = figures_from_configs([str(c) for c in h.configs])
        keys: dict[int, bytes] = {}
        for c in h.configs:
            for node, key in load_node_keys(c).items():
                if node in keys and keys[node] != key:
                    raise ValueError(f"{c}: node {node} has another key in an earlier config")
                keys[node] = key
    except ValueError as e:
        raise ValueError(f"hoist {h.id}: {e}") from None
    settings = dataclasses.replace(alarm_settings(figures, silent_s), nodes=tuple(sorted(keys)))
    return HoistSpec(h.id, figures, keys, settings, receivers=h.receivers, baud=h.baud, rs485=h.rs485,
                     name=h.name, config=h)


def build_hoist(spec: HoistSpec, clock: Callable[[], float], *, wall: Callable[[], float] = time.time,
                store: Any = None, db_path: Path | None = None, views: Iterable[Listener] = (),
                wake: threading.Event | None = None) -> Hoist:
    """The pipeline of `spec`: keys, listeners (alarm engine, `store`'s log, then `views`), the
    replay protection resumed from `store`. `clock` is the listeners' time, `wall` stamps the
    pipeline's own events, the frames' rx times and the link statistics; `wake` is set whenever
    something is queued for the pipeline. Ports are opened by `Hoist.start`."""
    listeners = station_listeners(spec.settings, store, *views, wall=wall)
    alarms = listeners[0]
    assert isinstance(alarms, AlarmListener)
    pipeline = HoistPipeline(spec.keys or None, listeners, clock=clock, accept_rewound=spec.accept_rewound,
                             resume_from=store, wall=wall, wake=wake)
    return Hoist(spec.id, spec.name or spec.id, spec.figures, spec.keys, pipeline, alarms, store, db_path,
                 spec.config, spec)


def step(pipelines: Iterable[HoistPipeline]) -> None:
    """One pump and tick of every pipeline, in order."""
    for p in pipelines:
        p.pump()
        p.tick()


def run_loop(pipelines: Sequence[HoistPipeline], period_s: float, done: Callable[[], bool] = lambda: False, *,
             wake: threading.Event | None = None, wait: Callable[[float], Any] | None = None,
             on_tick: Callable[[], None] | None = None, first_tick_s: float = 0.0) -> None:
    """Until `done()`: every `period_s` pump and tick every pipeline (then `on_tick()`, e.g. a
    display), and pump them between ticks whenever waiting ends early.

    The loop waits until the next tick with `wait(timeout)` (default: on `wake`, set when a
    frame or command is queued; without one, a sleep); a `wait` that returns True asks for a
    tick at once (a key pressed). The first tick comes `first_tick_s` after the start."""
    def rest(timeout: float) -> None:
        if wake is not None:
            wake.wait(timeout)
        else:
            time.sleep(timeout)

    wait_for = wait or rest
    next_tick = time.monotonic() + first_tick_s
    while not done():
        if wake is not None:
            wake.clear()
        if time.monotonic() >= next_tick:
            step(pipelines)
            next_tick = max(next_tick + period_s, time.monotonic() - period_s)
            if on_tick is not None:
                on_tick()
        else:
            for p in pipelines:
                p.pump()
        if wait_for(max(0.0, next_tick - time.monotonic())) is True:
            next_tick = time.monotonic()
