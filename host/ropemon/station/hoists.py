"""Several hoists in one station: one `Station` per hoist, run on one thread.

A station file (`ropemon.station.stationfile`) names the hoists, each with its node configs
and receivers. `StationSet` builds, per hoist, the same station `ropemon monitor` runs
(receivers, alarms, the hoist's log) and lets a face add its own listener to every hoist
(`add_listeners`) before the ports open. `run` pumps and ticks every hoist's station until
stopped; `submit` hands an operator's command to one hoist's station, from any thread.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ropemon.station.commands import Command, Ticket
from ropemon.station.pipeline import AlarmListener, Listener, Station, StoreListener
from ropemon.station.protocol import load_node_keys
from ropemon.station.sitefigures import SiteFigures, alarm_settings, site_from_configs
from ropemon.station.stationfile import HoistFile, StationFile


@dataclass
class Hoist:
    """One hoist of the station: its figures, its station and the listeners it was built with."""

    id: str
    name: str
    site: SiteFigures
    keys: dict[int, bytes]
    station: Station
    alarms: AlarmListener
    store: Any = None                 # ropemon.station.store.Store, or None without a data_dir
    db_path: Path | None = None
    spec: HoistFile | None = None


class StationSet:
    """The hoists of a station file, each with its own `Station` (module docstring)."""

    def __init__(self, sf: StationFile, clock: Callable[[], float] = time.time, open_stores: bool = True,
                 receivers: dict[str, list[tuple[str, str]]] | None = None) -> None:
        """`receivers` replaces the receivers of the hoists it names ({hoist id: [(name, pyserial
        URL)]}): the demo's virtual ports instead of the station file's adapters."""
        self.file = sf
        self.clock = clock
        self.hoists: dict[str, Hoist] = {}
        unknown = set(receivers or {}) - {h.id for h in sf.hoists}
        if unknown:
            raise ValueError(f"receivers given for hoists the station file does not have: {', '.join(sorted(unknown))}")
        if receivers:
            sf = dataclasses.replace(sf, hoists=tuple(
                dataclasses.replace(h, receivers=tuple(receivers[h.id])) if h.id in receivers else h
                for h in sf.hoists))
            self.file = sf
        self._stop = threading.Event()
        self._wake = threading.Event()     # frames or commands queued for a hoist's station
        try:
            for h in sf.hoists:
                self.hoists[h.id] = self._build(h, open_stores)
        except Exception:
            self.close()
            raise

    def _build(self, h: HoistFile, open_stores: bool) -> Hoist:
        where = f"hoist {h.id}"
        try:
            site = site_from_configs([str(c) for c in h.configs])
            keys: dict[int, bytes] = {}
            for c in h.configs:
                for node, key in load_node_keys(c).items():
                    if node in keys and keys[node] != key:
                        raise ValueError(f"{c}: node {node} has another key in an earlier config")
                    keys[node] = key
        except ValueError as e:
            raise ValueError(f"{where}: {e}") from None
        settings = dataclasses.replace(alarm_settings(site, self.file.silent_s), nodes=tuple(sorted(keys)))
        store = db_path = None
        if open_stores and self.file.data_dir is not None:
            from ropemon.station.store import Store
            self.file.data_dir.mkdir(parents=True, exist_ok=True)
            db_path = self.file.data_dir / f"{h.id}.db"
            store = Store(db_path)
        alarms = AlarmListener(settings)
        listeners: list[Listener] = [alarms] + ([StoreListener(store)] if store is not None else [])
        station = Station(keys, listeners, clock=self.clock, resume_from=store)
        return Hoist(h.id, h.name, site, keys, station, alarms, store, db_path, h)

    def add_listeners(self, factory: Callable[[Hoist], Listener | None]) -> None:
        """Add `factory(hoist)`'s listener to every hoist (call before `start`)."""
        for h in self.hoists.values():
            listener = factory(h)
            if listener is not None:
                h.station.add(listener)

    def start(self) -> None:
        """Open every hoist's receiver ports (each in its own reader thread)."""
        for h in self.hoists.values():
            assert h.spec is not None
            for name, url in h.spec.receivers:
                h.station.add_port(url, name, baudrate=h.spec.baud, rs485=h.spec.rs485).start()

    def step(self) -> None:
        """One pump and tick of every hoist's station."""
        for h in self.hoists.values():
            h.station.pump()
            h.station.tick()

    def run(self, done: Callable[[], bool] = lambda: False) -> None:
        """Until `stop()` or `done()`: hand frames and commands on as soon as a receiver or a
        face queues them, and tick every hoist every 1/tick_hz s (alarm timing, status)."""
        period = 1.0 / self.file.tick_hz
        wake = self._wake
        for h in self.hoists.values():
            h.station.hub.wake = wake
        next_tick = time.monotonic()
        while not self._stop.is_set() and not done():
            wake.clear()
            if time.monotonic() >= next_tick:
                self.step()
                next_tick = max(next_tick + period, time.monotonic() - period)
            else:
                for h in self.hoists.values():
                    h.station.pump()
            wake.wait(max(0.0, next_tick - time.monotonic()))

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()

    def submit(self, hoist_id: str, command: Command) -> Ticket:
        """An operator command for one hoist, from any thread (KeyError: no such hoist); the
        future its station settles with the command's outcome (`Station.submit`)."""
        return self.hoists[hoist_id].station.submit(command)

    def close(self) -> None:
        """Stop the ports, let every listener finish, close the logs."""
        for h in self.hoists.values():
            h.station.close()
            if h.store is not None:
                h.store.close()
