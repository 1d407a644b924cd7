"""The station: the hoists of a station file, one `HoistPipeline` each, run on one thread.

A station file (`ropemon.station.stationfile`, a `StationConfig`) names the hoists, each with
its node configs and receivers. `Station` builds each hoist's pipeline with
`assembly.build_hoist`, as `ropemon monitor` builds its one (receivers, alarms, the hoist's
log), and lets a face add its own listener to every hoist (`add_listeners`) before the ports
open. `run` pumps and ticks every hoist's pipeline on `assembly.run_loop` until stopped;
`submit` hands an operator's command to one hoist's pipeline, from any thread. The faces use
it as a `faces.StationView`.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from typing import Callable

from ropemon.station import assembly
from ropemon.station.assembly import Hoist, run_loop, spec_from_config, step
from ropemon.station.commands import Command, Ticket
from ropemon.station.pipeline import Listener
from ropemon.station.stationfile import HoistConfig, StationConfig

__all__ = ["Hoist", "Station"]


class Station:
    """The hoists of a station file, each with its own `HoistPipeline` (module docstring)."""

    def __init__(self, sf: StationConfig, clock: Callable[[], float] = time.time, open_stores: bool = True,
                 receivers: dict[str, list[tuple[str, str]]] | None = None,
                 wall: Callable[[], float] = time.time) -> None:
        """`receivers` replaces the receivers of the hoists it names ({hoist id: [(name, pyserial
        URL)]}): the demo's virtual ports instead of the station file's adapters. `clock` and
        `wall` as `assembly.build_hoist` takes them."""
        self.config = sf
        self.clock = clock
        self.wall = wall
        self.hoists: dict[str, Hoist] = {}
        unknown = set(receivers or {}) - {h.id for h in sf.hoists}
        if unknown:
            raise ValueError(f"receivers given for hoists the station file does not have: {', '.join(sorted(unknown))}")
        if receivers:
            sf = dataclasses.replace(sf, hoists=tuple(
                dataclasses.replace(h, receivers=tuple(receivers[h.id])) if h.id in receivers else h
                for h in sf.hoists))
            self.config = sf
        self._stop = threading.Event()
        self._wake = threading.Event()     # frames or commands queued for a hoist's station
        try:
            for h in sf.hoists:
                self.hoists[h.id] = self._build(h, open_stores)
        except Exception:
            self.close()
            raise

    def _build(self, h: HoistConfig, open_stores: bool) -> Hoist:
        spec = spec_from_config(h, self.config.silent_s)
        store = db_path = None
        if open_stores and self.config.data_dir is not None:
            from ropemon.station.store import Store
            self.config.data_dir.mkdir(parents=True, exist_ok=True)
            db_path = self.config.data_dir / f"{h.id}.db"
            store = Store(db_path)
        return assembly.build_hoist(spec, self.clock, wall=self.wall, store=store, db_path=db_path, wake=self._wake)

    def add_listeners(self, factory: Callable[[Hoist], Listener | None]) -> None:
        """Add `factory(hoist)`'s listener to every hoist (call before `start`)."""
        for h in self.hoists.values():
            listener = factory(h)
            if listener is not None:
                h.pipeline.add(listener)

    def start(self) -> None:
        """Open every hoist's receiver ports (each in its own reader thread)."""
        for h in self.hoists.values():
            h.start()

    def step(self) -> None:
        """One pump and tick of every hoist's station."""
        step(h.pipeline for h in self.hoists.values())

    def run(self, done: Callable[[], bool] = lambda: False) -> None:
        """Until `stop()` or `done()`: hand frames and commands on as soon as a receiver or a
        face queues them, and tick every hoist every 1/tick_hz s (alarm timing, status)."""
        run_loop([h.pipeline for h in self.hoists.values()], 1.0 / self.config.tick_hz,
                 lambda: self._stop.is_set() or done(), wake=self._wake)

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()

    def submit(self, hoist_id: str, command: Command) -> Ticket:
        """An operator command for one hoist, from any thread (KeyError: no such hoist); the
        future its pipeline settles with the command's outcome (`HoistPipeline.submit`)."""
        return self.hoists[hoist_id].pipeline.submit(command)

    def close(self) -> None:
        """Stop the ports, let every listener finish, close the logs."""
        for h in self.hoists.values():
            h.pipeline.close()
            if h.store is not None:
                h.store.close()
