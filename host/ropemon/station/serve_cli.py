"""`ropemon serve STATION.toml`: the station of a station file, with its faces, as a service.

Every hoist of the file gets the station `ropemon monitor` runs (receivers, alarms, its
log); the faces the file configures ([web], [opcua], [modbus], [mqtt]) are started on it
(`ropemon.station.faces`). Every alarm event is printed as one JSON line on stdout, as
`ropemon monitor --headless` does, with the hoist's id. On stderr: where each hoist's replay
protection resumed from its log (as `ropemon monitor` says it), each face's address, and
the log (`ropemon.station.logsummary`: repeated messages summarised). SIGTERM or SIGINT
stops it with everything committed.
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import IO

from ropemon.station import logsummary
from ropemon.station.alarms import AlarmEvent
from ropemon.station.pipeline import Listener


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("station", help="the station file (station.toml, docs/web.md)")
    p.add_argument("--quiet", action="store_true", help="do not print alarm events on stdout")


class HoistJsonLines(Listener):
    """Each alarm event of one hoist as a JSON line, with the hoist's id."""

    name = "json lines"

    def __init__(self, hoist: str, out: IO[str]) -> None:
        from ropemon.station.monitor import JsonAlarmLines
        self.hoist = hoist
        self._lines = JsonAlarmLines(_Prefix(out, hoist))

    def on_event(self, event: AlarmEvent) -> None:
        self._lines.on_event(event)


class _Prefix:
    """A stream that adds `"hoist": id` to each JSON object line written to it."""

    def __init__(self, out: IO[str], hoist: str) -> None:
        self.out, self.head = out, '{"hoist": "%s", ' % hoist

    def write(self, line: str) -> None:
        self.out.write(self.head + line[1:] if line.startswith("{") else line)

    def flush(self) -> None:
        self.out.flush()


def run(args: argparse.Namespace) -> int:
    from ropemon.station.faces import FaceError, start_faces
    from ropemon.station.hoists import Station
    from ropemon.station.stationfile import StationConfigError, load_station_file
    from ropemon.station.store import StoreError

    try:
        sf = load_station_file(args.station)
        station = Station(sf)
    except (StationConfigError, StoreError, ValueError, OSError) as e:
        print(f"ropemon serve: {e}", file=sys.stderr)
        return 2
    # the faces' messages, the web's logins and pymodbus's and asyncua's warnings, on stderr,
    # repeated ones summarised (a flood of bad traffic is a few lines a minute)
    logsummary.install(sys.stderr, "ropemon serve")
    for h in station.hoists.values():
        resumed = h.pipeline.resumed_text()
        if resumed is not None:
            print(f"ropemon serve: hoist {h.id}: {resumed}", file=sys.stderr)
    faces = []
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: (stop.set(), station.stop()))
    try:
        if not args.quiet:
            station.add_listeners(lambda h: HoistJsonLines(h.id, sys.stdout))
        try:
            faces = start_faces(station, sf)
        except (FaceError, ValueError) as e:
            print(f"ropemon serve: {e}", file=sys.stderr)
            return 2
        for f in faces:
            print(f"ropemon serve: {f.describe()}", file=sys.stderr)
        station.start()
        station.run(stop.is_set)
    finally:
        for f in faces:
            f.stop()
        station.close()
    return 0
