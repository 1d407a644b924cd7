"""`ropemon demo --station FILE` / `--serve`: the demo's wind through a station file's `StationSet`.

The station file is the demo's own (`write_demo_station`: one hoist, its log and the web face
in the demo's folder) or the one given; its first hoist's receivers become the demo's virtual
ports. The station is `ropemon serve`'s: the same `StationSet`, the same faces.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import Any, Callable

from ropemon.lab import radio
from ropemon.lab.demo import (DEMO_HOIST, DEMO_OPERATOR, DemoClock, DemoHost, FrameKeeper, start_players,
                              stop_players)
from ropemon.lab.localnet import free_port
from ropemon.station.assembly import run_loop
from ropemon.station.protocol import load_node_keys


def write_demo_station(out: Path, node_json: Path, shaft_m: float, port: int | None) -> tuple[Path, str]:
    """OUT/station.toml: one hoist (the simulated one), its log in OUT, the web face on localhost,
    and OUT/users.toml with one operator whose password is new each run (returned)."""
    import secrets

    try:
        from ropemon.station.users import add_user
    except ImportError as e:
        raise RuntimeError(f"--serve needs the web face's libraries: pip install 'ropemon[web]' ({e})") from None
    users = out / "users.toml"
    users.unlink(missing_ok=True)
    password = secrets.token_urlsafe(9)
    add_user(users, DEMO_OPERATOR, "operator", password)
    path = out / "station.toml"
    path.write_text(f"""# written by ropemon demo: the simulated hoist as a station (docs/web.md)
[station]
name = "ropemon demo"
data_dir = "."

[[hoist]]
id = "{DEMO_HOIST}"
name = "Simulated hoist"
configs = ["{node_json.resolve().relative_to(out.resolve()).as_posix()}"]
receivers = {{ pithead = "set by ropemon demo" }}
shaft_m = {max(shaft_m, 1.0):.1f}

[web]
bind = "127.0.0.1"
port = {port or free_port()}
view_without_login = true
users = "users.toml"
secret = "web-secret"
""")
    return path, password


def demo_station_file(args: argparse.Namespace, out: Path, node_json: Path, shaft_m: float,
                      step: Callable[[str], float]) -> tuple[Any, str | None, Path | None] | None:
    """(station file, the demo operator's password or None, the first hoist's log or None): the
    first hoist with the simulated node's config if its own lack its key, the demo's own log
    new each run; None after printing why a given station's log cannot take the demo's frames."""
    from ropemon.station.stationfile import load_station_file

    password = None
    if args.station:
        sf = load_station_file(args.station)
    else:
        path, password = write_demo_station(out, node_json, shaft_m, args.port)
        sf = load_station_file(path)
    first = sf.hoists[0]
    demo_keys = load_node_keys(node_json)
    have: dict[int, bytes] = {}
    for c in first.configs:
        have.update(load_node_keys(c))
    if any(have.get(n) != k for n, k in demo_keys.items()):
        step(f"  hoist {first.id}: its node configs do not hold the simulated node's key: it uses {node_json}")
        sf = dataclasses.replace(sf, hoists=(dataclasses.replace(first, configs=(node_json,)),) + sf.hoists[1:])
    db = sf.data_dir / f"{first.id}.db" if sf.data_dir is not None else None
    if db is not None and not args.station:          # the demo's own log: a new one each run
        for p in (db, Path(str(db) + "-wal"), Path(str(db) + "-shm")):
            p.unlink(missing_ok=True)
    elif db is not None and db.exists():
        from ropemon.station.store import Store
        with Store(db, readonly=True) as st:
            logged = set(st.last_seqs()) & set(demo_keys)
        if logged:
            print(f"ropemon demo: {db} already holds frames of node {sorted(logged)[0]}: the demo's frames would be "
                  "refused as replays; remove that log or give the station another data_dir", file=sys.stderr)
            return None
    return sf, password, db


def play_to_station(args: argparse.Namespace, out: Path, node_json: Path, site: Any, shaft_m: float,
                    deliveries: dict[str, list[radio.Delivery]], speed: float, clock: DemoClock, headless: bool,
                    step: Callable[[str], float], wind_s: float):
    """The wind through a station file's StationSet (the demo's own, or --station's first hoist),
    with its faces when serving. Returns (DemoHost, bytes written per receiver, the first hoist's
    log or None, finish) where finish() keeps serving until Ctrl-C (--serve in a terminal, unless
    the operator quit) and then closes everything; None after a refusal it printed."""
    import signal
    import threading

    from rich.console import Console, Group
    from rich.text import Text

    from ropemon.lab.vserial import VirtualPort
    from ropemon.station.faces import FaceError, start_faces
    from ropemon.station.hoists import StationSet
    from ropemon.station.monitor import MonitorView, live_loop

    got = demo_station_file(args, out, node_json, shaft_m, step)
    if got is None:
        return None
    sf, password, db = got
    first = sf.hoists[0]
    ports = {name: VirtualPort(name) for name in deliveries}
    stations: Any = None
    faces: list = []
    players: list = []

    def close() -> None:
        for p in players:
            p.stop()
        for f in faces:
            f.stop()
        if stations is not None:
            stations.close()
        for vp in ports.values():
            vp.close()

    try:
        stations = StationSet(sf, clock=clock, wall=clock,       # events and rx times on the demo's clock too
                              receivers={first.id: [(n, vp.port) for n, vp in ports.items()]})
        every = [h.station for h in stations.hoists.values()]
        h0 = stations.hoists[first.id]
        kept = FrameKeeper()
        view = None if headless else MonitorView(site)
        stations.add_listeners(lambda h: kept if h.id == first.id else None)
        if view is not None:
            stations.add_listeners(lambda h: view if h.id == first.id else None)
        if args.serve:
            try:
                faces = start_faces(stations, sf)
            except FaceError as e:
                raise RuntimeError(str(e)) from None
        urls = [u for u in (getattr(f, "url", None) for f in faces) if u]
        for f in faces:
            step(f"  {f.describe()}")
        if password is not None and urls:
            step(f"  web: log in as {DEMO_OPERATOR} / {password} to acknowledge and shelve (a new password each run)")
        stations.start()
        done = start_players(ports, deliveries, speed, h0.station, "station", players)
        step(f"  playing {wind_s:.0f} s of frames at {speed:g}x real time (about {wind_s / speed:.0f} s)"
             + (f"; the web page: {urls[0]}" if urls else ""))
        quit_early = False
        if view is not None:
            base_render = view.render
            head = Text(f" web: {urls[0]}  (the station keeps serving after the wind until Ctrl-C)" if urls else "",
                        style="bold cyan")
            view.render = lambda now: Group(head, base_render(now)) if urls else base_render(now)  # type: ignore
            console = Console()
            live_loop(h0.station, view, console, 4.0, done, stations=every)   # keys act on the first hoist
            quit_early = not done()
            console.print(view.render(stations.clock()))
        if not quit_early:
            run_loop(every, 1.0 / sf.tick_hz, done)
        written = stop_players(players)
        stations.step()
        if h0.store is not None:
            h0.store.commit()
        host = DemoHost(h0.station, h0.alarms, kept, h0.store, view)
    except BaseException:
        close()
        raise

    def finish() -> None:
        try:
            if args.serve and faces and not headless and not quit_early:
                stop = threading.Event()
                for sig in (signal.SIGTERM, signal.SIGINT):
                    signal.signal(sig, lambda *_: stop.set())
                print(f"[demo] the station keeps serving {urls[0] if urls else ''} until Ctrl-C", flush=True)
                stations.run(stop.is_set)
        finally:
            close()

    return host, written, db, finish
