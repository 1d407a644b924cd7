"""`ropemon demo --station FILE` / `--serve`: the demo's wind through a station file's `Station`.

The station file is the demo's own (`write_demo_station`: one hoist, its log and the web face
in the demo's folder) or the one given; its first hoist's receivers become the demo's virtual
ports. The station is `ropemon serve`'s: the same `Station`, the same faces. Of a given
file, the demo changes only what the simulated node cannot do without, in memory: the first
hoist's node configs when they lack the simulated node's key, and then the station's logs
(OUT/data: the simulated node's frames never go into the file's own); when serving, a users
file it names that does not exist (the demo's own, OUT/users.toml, with its operator).
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


def demo_users(out: Path) -> tuple[Path, str]:
    """OUT/users.toml with one operator, the demo's, whose password is new each run: (path, password)."""
    import secrets

    try:
        from ropemon.station.users import add_user
    except ImportError as e:
        raise RuntimeError(f"--serve needs the web face's libraries: pip install 'ropemon[web]' ({e})") from None
    users = out / "users.toml"
    users.unlink(missing_ok=True)
    password = secrets.token_urlsafe(9)
    add_user(users, DEMO_OPERATOR, "operator", password)
    return users, password


def with_demo_users(sf: Any, out: Path, step: Callable[[str], float]) -> tuple[Any, str | None]:
    """The station file with the demo's users file (`demo_users`) in place of every users file it
    names ([web], [opcua]) that does not exist, and the demo operator's password (None: none missing)."""
    web = sf.web.users if sf.web is not None else None
    opcua = sf.sections.get("opcua", {}).get("users")
    opcua_path = None
    if isinstance(opcua, str) and opcua:
        opcua_path = Path(opcua) if Path(opcua).is_absolute() else sf.path.parent / opcua
    missing = [p for p in dict.fromkeys((web, opcua_path)) if p is not None and not p.exists()]
    if not missing:
        return sf, None
    users, password = demo_users(out)
    for p in missing:
        step(f"  {p}: no such users file: the demo's {users} instead (its operator {DEMO_OPERATOR}, "
             "a new password each run)")
    if web in missing:
        sf = dataclasses.replace(sf, web=dataclasses.replace(sf.web, users=users))
    if opcua_path in missing:
        sf = dataclasses.replace(sf, sections={**sf.sections,
                                               "opcua": {**sf.sections["opcua"], "users": str(users.resolve())}})
    return sf, password


def write_demo_station(out: Path, node_json: Path, shaft_m: float, port: int | None) -> tuple[Path, str]:
    """OUT/station.toml: one hoist (the simulated one), its log in OUT, the web face on localhost,
    and OUT/users.toml with one operator whose password is new each run (returned)."""
    users, password = demo_users(out)
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
    first hoist with the simulated node's config if its own lack its key, and then the logs in
    OUT/data; the missing users files the demo's (`with_demo_users`, when serving); the demo's
    own log new each run; None after printing why a given station's log cannot take the demo's
    frames."""
    from ropemon.station.stationfile import load_station_file

    password = None
    if args.station:
        sf = load_station_file(args.station)
        if args.serve:
            sf, password = with_demo_users(sf, out, step)
    else:
        path, password = write_demo_station(out, node_json, shaft_m, args.port)
        sf = load_station_file(path)
    first = sf.hoists[0]
    demo_keys = load_node_keys(node_json)
    have: dict[int, bytes] = {}
    for c in first.configs:
        have.update(load_node_keys(c))
    own_log = not args.station
    if any(have.get(n) != k for n, k in demo_keys.items()):
        step(f"  hoist {first.id}: its node configs do not hold the simulated node's key: it uses {node_json}")
        sf = dataclasses.replace(sf, hoists=(dataclasses.replace(first, configs=(node_json,)),) + sf.hoists[1:])
        if sf.data_dir is not None:                   # another node's frames: not into the file's logs
            sf = dataclasses.replace(sf, data_dir=out / "data")
            own_log = True
            step(f"  the station's logs in {sf.data_dir} (the simulated node's frames stay out of the file's own)")
    db = sf.data_dir / f"{first.id}.db" if sf.data_dir is not None else None
    if db is not None and own_log:                   # the demo's own log: a new one each run
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
    """The wind through a station file's Station (the demo's own, or --station's first hoist),
    with its faces when serving. Returns (DemoHost, bytes written per receiver, the first hoist's
    log or None, finish) where finish() keeps serving until Ctrl-C (--serve in a terminal, unless
    the operator quit) and then closes everything; None after a refusal it printed."""
    import signal
    import threading

    from rich.console import Console, Group
    from rich.text import Text

    from ropemon.lab.vserial import VirtualPort
    from ropemon.station.faces import FaceError, start_faces
    from ropemon.station.hoists import Station
    from ropemon.station.monitor import MonitorView, live_loop

    got = demo_station_file(args, out, node_json, shaft_m, step)
    if got is None:
        return None
    sf, password, db = got
    first = sf.hoists[0]
    ports = {name: VirtualPort(name) for name in deliveries}
    station: Any = None
    faces: list = []
    players: list = []

    def close() -> None:
        for p in players:
            p.stop()
        for f in faces:
            f.stop()
        if station is not None:
            station.close()
        for vp in ports.values():
            vp.close()

    try:
        station = Station(sf, clock=clock, wall=clock,       # events and rx times on the demo's clock too
                          receivers={first.id: [(n, vp.port) for n, vp in ports.items()]})
        every = [h.pipeline for h in station.hoists.values()]
        h0 = station.hoists[first.id]
        kept = FrameKeeper()
        view = None if headless else MonitorView(site)
        station.add_listeners(lambda h: kept if h.id == first.id else None)
        if view is not None:
            station.add_listeners(lambda h: view if h.id == first.id else None)
        if args.serve:
            try:
                faces = start_faces(station, sf)
            except FaceError as e:
                raise RuntimeError(str(e)) from None
        urls = [u for u in (getattr(f, "url", None) for f in faces) if u]
        for f in faces:
            step(f"  {f.describe()}")
        if password is not None and urls:
            step(f"  web: log in as {DEMO_OPERATOR} / {password} to acknowledge and shelve (a new password each run)")
        station.start()
        done = start_players(ports, deliveries, speed, h0.pipeline, "station", players)
        step(f"  playing {wind_s:.0f} s of frames at {speed:g}x real time (about {wind_s / speed:.0f} s)"
             + (f"; the web page: {urls[0]}" if urls else ""))
        quit_early = False
        if view is not None:
            base_render = view.render
            head = Text(f" web: {urls[0]}  (the station keeps serving after the wind until Ctrl-C)" if urls else "",
                        style="bold cyan")
            view.render = lambda now: Group(head, base_render(now)) if urls else base_render(now)  # type: ignore
            console = Console()
            live_loop(h0.pipeline, view, console, 4.0, done, pipelines=every)   # keys act on the first hoist
            quit_early = not done()
            console.print(view.render(station.clock()))
        if not quit_early:
            run_loop(every, 1.0 / sf.tick_hz, done)
        written = stop_players(players)
        station.step()
        if h0.store is not None:
            h0.store.commit()
        host = DemoHost(h0.pipeline, h0.alarms, kept, h0.store, view)
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
                station.run(stop.is_set)
        finally:
            close()

    return host, written, db, finish
