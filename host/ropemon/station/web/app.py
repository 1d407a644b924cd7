"""The web face's routes: pages, server-sent event streams, operator actions (Starlette).

    GET  /                              overview of every hoist               (view)
    GET  /login, POST /login, POST /logout
    GET  /hoist/{id}                    the live page                         (view)
    GET  /hoist/{id}/stream             its server-sent events: snapshot, then deltas
    GET  /hoist/{id}/snapshot.json      the same snapshot once
    GET  /hoist/{id}/trends             live and historical trends; /history.json?node=&t0=&t1=
    GET  /hoist/{id}/log                the event and audit log (the store's events), filtered
    GET  /hoist/{id}/trips              the trips in the log; /trips/{n} (.csv, .json, .png)
    GET  /overview/stream               every hoist's summary as server-sent events
    POST /hoist/{id}/ack | shelve | unshelve | remove | return | accept-rewound   (login + CSRF)

An action becomes the station's command (`station.submit(hoist, Acknowledge(user, "web"))`),
carried out on the station's thread; the web never touches a listener or the alarm engine. The
response waits for the command's outcome (`commands.OUTCOME_WAIT_S` at most): refused by the
station 409 with its reason; not answered in time 200 with `pending` (it is carried out later).
Every refused input names its field and the reason (400); without a login 401 (a form is sent
to the login page), without the CSRF token 403, without the role for it 403; a login while the
hashing pool is full 429 (users.HashPool).

A login is a session of the station's (auth.Sessions): the cookie holds its id. Pages and
actions count as a session's activity; the page's own data requests (streams, .json) do not,
so a screen left open ends its session after web.session_idle_min.
"""
from __future__ import annotations

import asyncio
import datetime
import logging
import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import quote, urlencode

from starlette.applications import Starlette
from starlette.datastructures import FormData
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.middleware.sessions import SessionMiddleware
from starlette.requests import Request
from starlette.responses import (JSONResponse, PlainTextResponse, RedirectResponse, Response,
                                 StreamingResponse)
from starlette.routing import BaseRoute, Mount, Route
from starlette.staticfiles import StaticFiles
from starlette.templating import Jinja2Templates

import ropemon
from ropemon.station.commands import outcome_within
from ropemon.station.faces import StationView
from ropemon.station.pipeline import (AcceptRewound, Acknowledge, RemoveFromService, ReturnToService, Shelve,
                                      Unshelve)
from ropemon.station.store import StoreError
from ropemon.station.stationfile import WebConfig
from ropemon.station.web import logread
from ropemon.station.users import User, Users
from ropemon.station.web.auth import DEFAULT_IDLE_MIN, Sessions, csrf_ok, csrf_token
from ropemon.station.web.state import STALE_S, Subscriber, WebListener, dumps

audit = logging.getLogger("ropemon.web.audit")   # logins and logouts (`ropemon serve` prints it)

HERE = Path(__file__).parent
KEEPALIVE_S = 15.0         # an SSE comment this often keeps proxies and the browser's watchdog content
MAX_SHELVE_MIN = 720.0     # a shelved alarm returns within a shift at most
MAX_REASON = 200
MAX_FORM_FIELD = 256
ALARM_ID = re.compile(r"^(\*|[a-z_]{1,40}(:[A-Za-z0-9_.-]{1,40}){0,3})$")
SESSION_MAX_AGE_S = 12 * 3600
HISTORY_MAX_S = 31 * 24 * 3600


@dataclass
class Context:
    """What the routes need: the hoists, their listeners and log readers, the users."""

    station: StationView
    web: WebConfig
    listeners: dict[str, WebListener]
    readers: dict[str, logread.LogReader]
    users: Users
    sessions: Sessions = None  # type: ignore[assignment]   # made on `users` with web.session_idle_min
    started_s: float = field(default_factory=time.time)

    def __post_init__(self) -> None:
        if self.sessions is None:
            idle_min = getattr(self.web, "session_idle_min", DEFAULT_IDLE_MIN)
            self.sessions = Sessions(self.users, idle_min * 60.0)


class Refused(Exception):
    """An input refused: field and reason (400)."""

    def __init__(self, field: str, reason: str, status: int = 400) -> None:
        super().__init__(f"{field}: {reason}")
        self.field, self.reason, self.status = field, reason, status


# -- helpers -------------------------------------------------------------------------------


def _ctx(request: Request) -> Context:
    return request.app.state.ctx


def _user(request: Request, touch: bool = True) -> User | None:
    """The request's logged-in user, or None (the id of a session that has ended is dropped from
    the cookie). `touch`: the request counts as the session's activity (pages and actions)."""
    cached = request.scope.get("ropemon.user", False)
    if cached is not False:
        return cached
    sid = request.session.get("sid")
    user = _ctx(request).sessions.user(sid, touch=touch) if sid else None
    if sid and user is None:
        request.session.pop("sid", None)
    request.scope["ropemon.user"] = user
    return user


def _wants_json(request: Request) -> bool:
    return (request.headers.get("x-requested-with") == "fetch"
            or "application/json" in request.headers.get("accept", ""))


def _hoist(request: Request) -> WebListener:
    hid = request.path_params["hoist"]
    lst = _ctx(request).listeners.get(hid)
    if lst is None:
        raise HTTPException(404, f"no hoist {hid!r} on this station")
    return lst


def _may_view(request: Request, touch: bool = True) -> bool:
    return bool(_ctx(request).web.view_without_login or _user(request, touch) is not None)


def _login_redirect(request: Request) -> RedirectResponse:
    nxt = request.url.path + (f"?{request.url.query}" if request.url.query else "")
    return RedirectResponse(f"/login?next={quote(nxt)}", status_code=303)


def _ts(t: float | None, date: bool = True) -> str:
    """A station time (epoch seconds) as the station's local time."""
    if t is None or not math.isfinite(t):
        return ""
    d = datetime.datetime.fromtimestamp(t)
    return d.strftime("%Y-%m-%d %H:%M:%S" if date else "%H:%M:%S")


def _num(x: Any, fmt: str = ".1f", none: str = "–") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return none
    return format(x, fmt)


templates = Jinja2Templates(directory=str(HERE / "templates"))
templates.env.filters["ts"] = _ts
templates.env.filters["num"] = _num
templates.env.globals["version"] = getattr(ropemon, "__version__", "0")


def _page(request: Request, name: str, ctx: dict, status: int = 200) -> Response:
    c = _ctx(request)
    user = _user(request)
    base = {
        "user": user, "csrf": csrf_token(request.session), "station_name": c.station.config.name,
        "hoists": [{"id": h.id, "name": h.name} for h in c.station.hoists.values()],
        "hoist": None, "stale_s": STALE_S, "flash": request.session.pop("flash", None),
        "may": (lambda action: bool(user and user.may(action))),
        "view_without_login": c.web.view_without_login, "path": request.url.path,
    }
    base.update(ctx)
    return templates.TemplateResponse(request, name, base, status_code=status)


def _field(form: FormData, name: str, required: bool = True) -> str:
    v = form.get(name)
    if v is None or (isinstance(v, str) and not v.strip() and required):
        if required:
            raise Refused(name, "missing")
        return ""
    if not isinstance(v, str):
        raise Refused(name, "must be text, not a file")
    if len(v) > MAX_FORM_FIELD:
        raise Refused(name, f"longer than {MAX_FORM_FIELD} characters")
    return v.strip()


def _text(form: FormData, name: str) -> str | None:
    v = form.get(name)
    return v if isinstance(v, str) else None


def _alarm(form: FormData, lst: WebListener, allow_all: bool = False) -> str:
    a = _field(form, "alarm")
    if not ALARM_ID.match(a) or (a == "*" and not allow_all):
        raise Refused("alarm", f"{a!r} is not an alarm id")
    if a != "*" and a not in lst.alarm_ids():
        raise Refused("alarm", f"no alarm {a!r} on hoist {lst.hoist_id} now")
    return a


def _reason(form: FormData) -> str:
    r = _field(form, "reason")
    if len(r) < 3:
        raise Refused("reason", "at least 3 characters: say why")
    if len(r) > MAX_REASON:
        raise Refused("reason", f"at most {MAX_REASON} characters")
    if any(ord(c) < 32 or ord(c) == 127 for c in r):
        raise Refused("reason", "no control characters")
    return r


def _minutes(form: FormData) -> float:
    text = _field(form, "minutes")
    try:
        m = float(text)
    except ValueError:
        raise Refused("minutes", f"must be a number, got {text!r}") from None
    if not math.isfinite(m) or not 1.0 <= m <= MAX_SHELVE_MIN:
        raise Refused("minutes", f"must be between 1 and {MAX_SHELVE_MIN:.0f}, got {text}")
    return m


def _node(form: FormData, lst: WebListener) -> int:
    text = _field(form, "node")
    if not re.fullmatch(r"\d{1,3}", text) or int(text) > 255:
        raise Refused("node", f"must be a node id 0-255, got {text!r}")
    node = int(text)
    if node not in lst.refused_nodes():
        raise Refused("node", f"node {node} is not refused for a boot counter gone back")
    return node


# -- pages ---------------------------------------------------------------------------------


async def overview(request: Request) -> Response:
    if not _may_view(request):
        return _login_redirect(request)
    c = _ctx(request)
    cards = [lst.summary() for lst in c.listeners.values()]
    return _page(request, "overview.html", {"cards": cards, "title": "overview", "page": "overview"})


async def live(request: Request) -> Response:
    lst = _hoist(request)
    if not _may_view(request):
        return _login_redirect(request)
    snap = lst.snapshot(trend=False)
    return _page(request, "live.html", {"hoist": {"id": lst.hoist_id, "name": lst.hoist_name}, "snap": snap,
                                        "title": lst.hoist_name, "page": "live"})


async def snapshot_json(request: Request) -> Response:
    lst = _hoist(request)
    if not _may_view(request, touch=False):
        return JSONResponse({"error": "log in to view"}, 401)
    return Response(dumps(lst.snapshot()), media_type="application/json")


def _sse(event: str, data: str) -> str:
    return f"event: {event}\ndata: {data}\n\n"


STREAM_RECHECK_S = 5.0     # a stream that needs a login checks its session this often (it ends with it)
_QUIET = object()          # nothing came within KEEPALIVE_S


async def _stream(request: Request, subscribe: Any, unsubscribe: Any, first: str) -> StreamingResponse:
    sub = Subscriber(asyncio.get_running_loop())
    snap = subscribe(sub)
    c = _ctx(request)
    sid = None if c.web.view_without_login else request.session.get("sid")

    async def gen() -> Any:
        checked = time.monotonic()
        try:
            yield "retry: 2000\n" + _sse(first, snap)
            while True:
                item: Any
                try:
                    item = await asyncio.wait_for(sub.queue.get(), KEEPALIVE_S)
                except asyncio.TimeoutError:
                    item = _QUIET
                if sid is not None and time.monotonic() - checked >= STREAM_RECHECK_S:
                    if c.sessions.user(sid, touch=False) is None:
                        yield _sse("session_ended", "{}")   # logged out, or ended otherwise: the page
                        break                                # goes to the login form
                    checked = time.monotonic()
                if item is _QUIET:
                    yield ": keepalive\n\n"
                    continue
                if item is None:
                    if sub.dropped:
                        yield _sse("dropped", "{}")
                    break
                yield _sse(*item)
        finally:
            unsubscribe(sub)

    return StreamingResponse(gen(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


async def hoist_stream(request: Request) -> Response:
    lst = _hoist(request)
    if not _may_view(request, touch=False):
        return PlainTextResponse("log in to view", 401)
    return await _stream(request, lst.subscribe, lst.unsubscribe, "snapshot")


async def overview_stream(request: Request) -> Response:
    if not _may_view(request, touch=False):
        return PlainTextResponse("log in to view", 401)
    lsts = list(_ctx(request).listeners.values())

    def subscribe(sub: Subscriber) -> str:
        return "[" + ",".join(lst.subscribe_summary(sub) for lst in lsts) + "]"

    def unsubscribe(sub: Subscriber) -> None:
        for lst in lsts:
            lst.unsubscribe(sub)

    return await _stream(request, subscribe, unsubscribe, "overview")


async def trends(request: Request) -> Response:
    lst = _hoist(request)
    if not _may_view(request):
        return _login_redirect(request)
    snap = lst.snapshot(trend=False)
    return _page(request, "trends.html", {"hoist": {"id": lst.hoist_id, "name": lst.hoist_name},
                                          "nodes": sorted(int(n) for n in snap["nodes"]),
                                          "has_log": _ctx(request).readers[lst.hoist_id].path is not None,
                                          "title": f"{lst.hoist_name}: trends", "page": "trends"})


def _query_float(request: Request, name: str, default: float | None) -> float | None:
    v = request.query_params.get(name)
    if v is None or v == "":
        return default
    try:
        x = float(v)
    except ValueError:
        raise Refused(name, f"must be a number, got {v[:40]!r}") from None
    if not math.isfinite(x):
        raise Refused(name, "must be finite")
    return x


def _query_int(request: Request, name: str, lo: int, hi: int) -> int | None:
    v = request.query_params.get(name)
    if v is None or v == "":
        return None
    if not re.fullmatch(r"-?\d{1,9}", v) or not lo <= int(v) <= hi:
        raise Refused(name, f"must be a whole number {lo}-{hi}, got {v[:40]!r}")
    return int(v)


async def history_json(request: Request) -> Response:
    lst = _hoist(request)
    if not _may_view(request, touch=False):
        return JSONResponse({"error": "log in to view"}, 401)
    now = lst.now or time.time()           # the station's clock
    node = _query_int(request, "node", 0, 255)
    if node is None:
        raise Refused("node", "missing")
    hours = _query_float(request, "hours", None)
    if hours is not None and not 0 < hours <= HISTORY_MAX_S / 3600:
        raise Refused("hours", f"must be more than 0 and at most {HISTORY_MAX_S // 3600}")
    t1 = _query_float(request, "t1", now)
    t0 = _query_float(request, "t0", (t1 or now) - (hours or 1.0) * 3600)
    assert t0 is not None and t1 is not None
    if not t0 < t1:
        raise Refused("t0", "must be before t1")
    if t1 - t0 > HISTORY_MAX_S:
        raise Refused("t0", f"a range of at most {HISTORY_MAX_S // 86400} days")
    reader = _ctx(request).readers[lst.hoist_id]
    try:
        data = await reader.call(logread.history, node, t0, t1)
    except StoreError as e:
        return JSONResponse({"error": str(e)}, 404)
    return Response(dumps(data), media_type="application/json")


async def log_page(request: Request) -> Response:
    lst = _hoist(request)
    if not _may_view(request):
        return _login_redirect(request)
    q = request.query_params
    action = q.get("action") or None
    if action is not None and action not in logread.EVENT_ACTIONS:
        raise Refused("action", f"must be one of {', '.join(logread.EVENT_ACTIONS)}")
    kind = q.get("kind") or None
    if kind is not None and not re.fullmatch(r"[a-z_]{1,40}", kind):
        raise Refused("kind", "an alarm kind: a-z and '_'")
    node = _query_int(request, "node", 0, 255)
    text = (q.get("text") or "")[:100] or None
    hours = _query_float(request, "hours", None)
    if hours is not None and not 0 < hours <= HISTORY_MAX_S / 3600:
        raise Refused("hours", f"must be more than 0 and at most {HISTORY_MAX_S // 3600}")
    limit = _query_int(request, "limit", 1, logread.MAX_EVENTS) or 500
    audit = q.get("audit") == "1"
    reader = _ctx(request).readers[lst.hoist_id]
    error = None
    rows: list[dict] = []
    kinds: list[str] = []
    try:
        t0 = (lst.now or time.time()) - hours * 3600 if hours else None
        rows = await reader.call(logread.events, action, kind, node, text, t0, None, audit, limit)
        kinds = await reader.call(logread.event_kinds)
    except StoreError as e:
        error = str(e)
    filters = {"action": action or "", "kind": kind or "", "node": "" if node is None else node, "text": text or "",
               "hours": "" if hours is None else q.get("hours"), "limit": limit, "audit": audit}
    return _page(request, "log.html", {"hoist": {"id": lst.hoist_id, "name": lst.hoist_name}, "rows": rows,
                                       "kinds": kinds, "actions": logread.EVENT_ACTIONS, "filters": filters,
                                       "error": error, "title": f"{lst.hoist_name}: log", "page": "log"})


async def trips_page(request: Request) -> Response:
    lst = _hoist(request)
    if not _may_view(request):
        return _login_redirect(request)
    reader = _ctx(request).readers[lst.hoist_id]
    error, rows = None, []
    try:
        rows = await reader.call(logread.trip_list)
    except StoreError as e:
        error = str(e)
    show_all = request.query_params.get("all") == "1"
    shown = rows if show_all else [r for r in rows if r["wind"]]
    return _page(request, "trips.html", {"hoist": {"id": lst.hoist_id, "name": lst.hoist_name}, "rows": shown,
                                         "hidden": len(rows) - len(shown), "show_all": show_all, "error": error,
                                         "title": f"{lst.hoist_name}: trips", "page": "trips"})


async def _trip(request: Request) -> tuple[WebListener, dict]:
    lst = _hoist(request)
    text = request.path_params["trip"]
    if not re.fullmatch(r"\d{1,12}", text):
        raise Refused("trip", f"a trip number, got {text[:20]!r}")
    c = _ctx(request)
    h = c.station.hoists[lst.hoist_id]
    config = getattr(h, "config", None)
    try:
        detail = await c.readers[lst.hoist_id].call(logread.trip_detail, int(text), h.figures.cylinder_area_m2,
                                                    getattr(config, "shaft_m", None))
    except StoreError as e:
        raise HTTPException(404, str(e)) from None
    if detail is None:
        raise HTTPException(404, f"no trip {text} in the log of hoist {lst.hoist_id}")
    return lst, detail


async def trip_page(request: Request) -> Response:
    if not _may_view(request):
        return _login_redirect(request)
    lst, d = await _trip(request)
    table = logread.rest_rows(d["report"]) if d["report"] is not None else None
    try:
        import matplotlib  # noqa: F401  (the report extra draws the PNG)
        png = True
    except ImportError:
        png = False
    return _page(request, "trip.html", {"hoist": {"id": lst.hoist_id, "name": lst.hoist_name}, "trip": d["trip"],
                                        "travel_m": d["travel_m"], "table": table, "report": d["report"],
                                        "png": png and d["report"] is not None,
                                        "title": f"{lst.hoist_name}: trip {d['trip'].id}", "page": "trip"})


async def trip_json(request: Request) -> Response:
    if not _may_view(request, touch=False):
        return JSONResponse({"error": "log in to view"}, 401)
    _lst, d = await _trip(request)
    if d["frames"] is None:
        return JSONResponse({"error": "no frames with ropes for this trip"}, 404)
    return Response(dumps(logread.trip_series(d)), media_type="application/json")


async def trip_csv(request: Request) -> Response:
    if not _may_view(request):                    # a download someone clicked: use
        return PlainTextResponse("log in to view", 401)
    lst, d = await _trip(request)
    if d["frames"] is None:
        return PlainTextResponse("no frames with ropes for this trip", 404)
    name = f"{lst.hoist_id}-trip{d['trip'].id}.csv"
    return Response(logread.trip_csv(d), media_type="text/csv",
                    headers={"Content-Disposition": f'attachment; filename="{name}"'})


async def trip_png(request: Request) -> Response:
    if not _may_view(request, touch=False):
        return PlainTextResponse("log in to view", 401)
    lst, d = await _trip(request)
    if d["report"] is None:
        return PlainTextResponse("no frames with ropes for this trip", 404)
    try:
        data = await asyncio.get_running_loop().run_in_executor(None, logread.trip_png, d)
    except ImportError:
        return PlainTextResponse("the plot needs matplotlib: pip install 'ropemon[report]'", 404)
    return Response(data, media_type="image/png")


# -- login ------------------------------------------------------------------------------------


async def login_form(request: Request) -> Response:
    nxt = request.query_params.get("next", "/")
    return _page(request, "login.html", {"next": _safe_next(nxt), "error": None, "title": "log in", "page": "login",
                                         "no_users": not _ctx(request).users.all()})


def _safe_next(nxt: str) -> str:
    """Only a path on this site (no //host, no scheme)."""
    return nxt if nxt.startswith("/") and not nxt.startswith("//") and "\\" not in nxt else "/"


async def login(request: Request) -> Response:
    form = await request.form()
    if not csrf_ok(request.session, _text(form, "csrf")):
        return PlainTextResponse("csrf: missing or wrong token (reload the login page)", 403)
    name = form.get("name")
    pw = form.get("password")
    nxt = _safe_next(str(form.get("next") or "/"))
    c = _ctx(request)
    user: User | None = None
    why: str | None = None
    if not isinstance(name, str) or not isinstance(pw, str) or not name or not pw \
            or len(name) > 64 or len(pw) > 1024:
        user, why = None, "give a name and a password"
    where = request.client.host if request.client else "?"
    busy = False
    if why is None:      # on the hashing pool (at most users.HASH_WORKERS at once), or refused at once
        res = await asyncio.wrap_future(c.users.start_login(str(name), str(pw), where))
        user, why, busy = res.user, res.why, res.busy
    if user is None:
        audit.warning("login refused: %r from %s: %s", name[:64] if isinstance(name, str) else None, where, why)
        page = _page(request, "login.html", {"next": nxt, "error": why, "title": "log in", "page": "login",
                                             "no_users": not c.users.all()}, status=429 if busy else 401)
        if busy:
            page.headers["Retry-After"] = "1"
        return page
    audit.info("login: %s (%s) from %s", user.name, user.role, where)
    request.session.clear()                 # a new session for the user (no fixation)
    request.session["sid"] = c.sessions.new(user)
    csrf_token(request.session)
    return RedirectResponse(nxt, status_code=303)


async def logout(request: Request) -> Response:
    form = await request.form()
    if not csrf_ok(request.session, _text(form, "csrf")):
        return PlainTextResponse("csrf: missing or wrong token", 403)
    c = _ctx(request)
    name = c.sessions.name(request.session.get("sid"))
    if name:             # every session of the user ends, not only this one
        c.sessions.end_user(name)
        audit.info("logout: %s from %s", name, request.client.host if request.client else "?")
    request.session.clear()
    return RedirectResponse("/", status_code=303)


# -- actions ----------------------------------------------------------------------------------


def _act(action: str) -> Any:
    async def handler(request: Request) -> Response:
        lst = _hoist(request)
        user = _user(request)
        as_json = _wants_json(request)
        if user is None:
            if as_json:
                return JSONResponse({"ok": False, "error": "log in as an operator to act"}, 401)
            return RedirectResponse(f"/login?next={quote('/hoist/' + lst.hoist_id)}", status_code=303)
        form = await request.form()
        token = request.headers.get("x-csrf-token") or _text(form, "csrf")
        if not csrf_ok(request.session, token):
            return JSONResponse({"ok": False, "field": "csrf", "error": "missing or wrong CSRF token (reload the page)"},
                                403)
        if not user.may(action):
            return JSONResponse({"ok": False, "error": f"{user.name} is a {user.role}: {action} needs an "
                                 f"{'engineer' if action in ('remove', 'return') else 'operator'}"}, 403)
        c = _ctx(request)
        who, via = user.name, "web"
        try:
            if action == "ack":
                alarm = _alarm(form, lst, allow_all=True)
                cmd: Any = Acknowledge(who, via, alarm=alarm)
                done = "acknowledged " + ("all alarms" if alarm == "*" else alarm)
            elif action == "shelve":
                alarm, reason, minutes = _alarm(form, lst), _reason(form), _minutes(form)
                cmd = Shelve(who, via, alarm=alarm, minutes=minutes, reason=reason)
                done = f"shelved {alarm} for {minutes:g} min"
            elif action == "unshelve":
                alarm = _alarm(form, lst)
                cmd = Unshelve(who, via, alarm=alarm)
                done = f"unshelved {alarm}"
            elif action == "remove":
                alarm, reason = _alarm(form, lst), _reason(form)
                cmd = RemoveFromService(who, via, alarm=alarm, reason=reason)
                done = f"took {alarm} out of service"
            elif action == "return":
                alarm = _alarm(form, lst)
                cmd = ReturnToService(who, via, alarm=alarm)
                done = f"returned {alarm} to service"
            else:
                node = _node(form, lst)
                cmd = AcceptRewound(who, via, node=node, how="from the web page")
                done = f"accepted node {node}"
        except Refused as e:
            if as_json:
                return JSONResponse({"ok": False, "field": e.field, "error": e.reason}, e.status)
            request.session["flash"] = f"refused: {e.field}: {e.reason}"
            return RedirectResponse(f"/hoist/{lst.hoist_id}", status_code=303)
        out = await outcome_within(c.station.submit(lst.hoist_id, cmd))
        if out is not None and not out.ok:
            if as_json:
                return JSONResponse({"ok": False, "refused": True, "error": out.reason}, 409)
            request.session["flash"] = f"refused: {out.reason}"
            return RedirectResponse(f"/hoist/{lst.hoist_id}", status_code=303)
        if out is None:
            done += " (the station has not answered yet)"
        if as_json:
            return JSONResponse({"ok": True, "done": done, **({"pending": True} if out is None else {})})
        request.session["flash"] = done
        return RedirectResponse(f"/hoist/{lst.hoist_id}", status_code=303)

    return handler


# -- the app ----------------------------------------------------------------------------------


async def _refused(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, Refused)
    if _wants_json(request) or request.url.path.endswith(".json"):
        return JSONResponse({"ok": False, "field": exc.field, "error": exc.reason}, exc.status)
    return PlainTextResponse(f"refused: {exc.field}: {exc.reason}", exc.status)


CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; connect-src 'self'; "
       "media-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'")


class SecurityHeaders:
    """CSP (scripts and styles from this site only), no framing, no sniffing, no referrer to others."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with(message: dict) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                headers += [(b"content-security-policy", CSP.encode()), (b"x-frame-options", b"DENY"),
                            (b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"same-origin")]
                message = dict(message, headers=headers)
            await send(message)

        await self.app(scope, receive, send_with)


def build_app(ctx: Context, secret: str, https_only: bool = False) -> Starlette:
    h = "/hoist/{hoist:str}"
    routes: list[BaseRoute] = [
        Route("/", overview),
        Route("/favicon.ico", lambda request: Response(status_code=204)),
        Route("/login", login_form, methods=["GET"]),
        Route("/login", login, methods=["POST"]),
        Route("/logout", logout, methods=["POST"]),
        Route("/overview/stream", overview_stream),
        Route(h, live),
        Route(h + "/stream", hoist_stream),
        Route(h + "/snapshot.json", snapshot_json),
        Route(h + "/trends", trends),
        Route(h + "/history.json", history_json),
        Route(h + "/log", log_page),
        Route(h + "/trips", trips_page),
        Route(h + "/trips/{trip:str}.json", trip_json),
        Route(h + "/trips/{trip:str}.csv", trip_csv),
        Route(h + "/trips/{trip:str}.png", trip_png),
        Route(h + "/trips/{trip:str}", trip_page),
    ]
    for action, path in (("ack", "ack"), ("shelve", "shelve"), ("unshelve", "unshelve"), ("remove", "remove"),
                         ("return", "return"), ("accept_rewound", "accept-rewound")):
        routes.append(Route(f"{h}/{path}", _act(action), methods=["POST"]))
    routes.append(Mount("/static", StaticFiles(directory=str(HERE / "static")), name="static"))
    middleware = [
        Middleware(SecurityHeaders),
        Middleware(SessionMiddleware, secret_key=secret, session_cookie="ropemon_session",
                   max_age=SESSION_MAX_AGE_S, same_site="strict", https_only=https_only),
    ]
    app = Starlette(routes=routes, middleware=middleware, exception_handlers={Refused: _refused})
    app.state.ctx = ctx
    return app


def query(**kw: Any) -> str:
    return urlencode({k: v for k, v in kw.items() if v not in (None, "")})


templates.env.globals["query"] = query
