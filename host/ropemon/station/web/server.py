"""The web face (`ropemon serve` with a [web] table): `start(view, web_config) -> WebFace`.

`attach` adds a `WebListener` to every hoist's station (before its receivers open) and builds
the Starlette app (`ropemon.station.web.app`) on them; `start` also runs uvicorn on it in a
daemon thread with its own asyncio loop, bound to web.bind:web.port (localhost unless told
otherwise), with TLS when web.tls_cert and web.tls_key are given. The station's thread only
ever hands copies and messages to the web's loop (`state.Subscriber`); the web only submits
commands (`Station.submit`).
"""
from __future__ import annotations

import asyncio
import logging
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

from ropemon.station.faces import StationView
from ropemon.station.stationfile import WebConfig
from ropemon.station.web import logread
from ropemon.station.web.app import Context, build_app
from ropemon.station.users import Users, UsersError
from ropemon.station.web.auth import load_secret
from ropemon.station.web.state import WebListener

START_TIMEOUT_S = 10.0
log = logging.getLogger("ropemon.web")


class WebError(ValueError):
    """The web face cannot start: the message names the field and the reason."""


@dataclass
class Attached:
    app: Any
    ctx: Context


def attach(view: StationView, web: WebConfig, users: Users | None = None, secret: str | None = None) -> Attached:
    """A WebListener on every hoist and the app on them (no server: `start` runs one)."""
    try:
        users = users if users is not None else Users(web.users)
        secret = secret if secret is not None else load_secret(web.secret)
    except (UsersError, OSError) as e:
        raise WebError(f"web: {e}") from None
    listeners: dict[str, WebListener] = {}

    def factory(h: Any) -> WebListener:
        listeners[h.id] = WebListener(h)
        return listeners[h.id]

    view.add_listeners(factory)
    readers = {hid: logread.LogReader(h.db_path) for hid, h in view.hoists.items()}
    ctx = Context(view, web, listeners, readers, users)
    return Attached(build_app(ctx, secret, https_only=web.tls_cert is not None), ctx)


class WebFace:
    """The running web server (the faces contract: `stop()`, `describe()`)."""

    def __init__(self, attached: Attached, web: WebConfig) -> None:
        import uvicorn

        self.attached = attached
        self.web = web
        self.scheme = "https" if web.tls_cert is not None else "http"
        kw: dict[str, Any] = {}
        if web.tls_cert is not None:
            kw = {"ssl_certfile": str(web.tls_cert), "ssl_keyfile": str(web.tls_key)}
        self.config = uvicorn.Config(attached.app, host=web.bind, port=web.port, log_level="warning",
                                     access_log=False, lifespan="off", timeout_graceful_shutdown=2,
                                     server_header=False, **kw)
        self.server = uvicorn.Server(self.config)
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, name="ropemon-web", daemon=True)

    def _run(self) -> None:
        try:
            asyncio.run(self.server.serve())
        except BaseException as e:  # SystemExit from uvicorn when it cannot bind
            self.error = e

    def start(self) -> "WebFace":
        self.thread.start()
        deadline = time.monotonic() + START_TIMEOUT_S
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                self.server.should_exit = True
                why = "it did not start in time" if self.thread.is_alive() else (
                    f"{type(self.error).__name__}: {self.error}" if self.error and not isinstance(self.error, SystemExit)
                    else "the address is in use or not this machine's")
                raise WebError(f"web: cannot listen on {self.web.bind}:{self.web.port}: {why}")
            time.sleep(0.02)
        return self

    @property
    def port(self) -> int:
        for s in self.server.servers:
            for sock in s.sockets:
                return int(sock.getsockname()[1])
        return int(self.web.port)

    @property
    def url(self) -> str:
        host = self.web.bind
        if host in ("0.0.0.0", "::", ""):
            host = "localhost"
        if ":" in host:
            host = f"[{host}]"
        return f"{self.scheme}://{host}:{self.port}/"

    def describe(self) -> str:
        ctx = self.attached.ctx
        n = len(ctx.users.all())
        view = "view without login" if self.web.view_without_login else "login needed to view"
        users = f"{n} user{'s' if n != 1 else ''} in {self.web.users}" if self.web.users else \
            "no users file: nobody can act from the web"
        return f"web: {self.url} ({len(ctx.listeners)} hoist{'s' if len(ctx.listeners) != 1 else ''}; {view}; {users})"

    def stop(self) -> None:
        for lst in self.attached.ctx.listeners.values():
            lst.close_subscribers()
        self.server.should_exit = True
        self.thread.join(5.0)
        for r in self.attached.ctx.readers.values():
            r.close()


def start(view: StationView, web: WebConfig) -> WebFace:
    """The faces contract (`ropemon.station.faces`): the web face, serving."""
    if sys.version_info < (3, 11):  # pragma: no cover
        raise WebError("web: needs Python 3.11")
    return WebFace(attach(view, web), web).start()
