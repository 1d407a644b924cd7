"""The web face (ropemon.station.web) through Starlette's TestClient, on a Station fed frames.

The station's thread is the test's: frames are fed and `step()` pumps and ticks, as
`Station.run` would; the app runs in the TestClient's own thread and loop.
"""
from __future__ import annotations

import concurrent.futures
import json
import os
import re
import stat
import time

import pytest
from argon2 import PasswordHasher

from ropemon.commission.nodejson import example_physical, make_node_json
from ropemon.station.hoists import Station
from ropemon.station.protocol import L, encode_frame
from ropemon.station.stationfile import load_station_file
from ropemon.station.store import Store

starlette_testclient = pytest.importorskip("starlette.testclient")
from ropemon.station.web import auth  # noqa: E402
from ropemon.station import users as accounts  # noqa: E402
from ropemon.station.users import Users, UsersError, add_user, load_users  # noqa: E402
from ropemon.station.web.server import WebError, attach  # noqa: E402

KEY_N, KEY_S = bytes(range(16)), bytes(range(1, 17))
CHEAP = PasswordHasher(time_cost=1, memory_cost=8, parallelism=1)   # test users only: fast to check
PASSWORDS = {"olga": "olga's long secret", "vic": "vic's long secret", "erin": "erin's long secret"}

STATION = """
[station]
name = "No. 2 shaft"
data_dir = "data"

[[hoist]]
id = "north"
name = "North shaft"
configs = ["north.json"]
receivers = { pithead = "loop://" }

[[hoist]]
id = "south"
name = "South shaft"
configs = ["south.json"]
receivers = { pithead = "loop://" }

[web]
users = "users.toml"
secret = "web-secret"
"""


def node_json(tmp_path, name: str, node: int, key: bytes) -> None:
    (tmp_path / name).write_text(json.dumps(make_node_json(example_physical(), node_id=node, key=key)))


class Site:
    """A station of two hoists with the web face attached (no server), and a clock."""

    def __init__(self, tmp_path, station_text: str = STATION, users: bool = True) -> None:
        node_json(tmp_path, "north.json", 1, KEY_N)
        node_json(tmp_path, "south.json", 1, KEY_S)
        if users:
            for name, role in (("olga", "operator"), ("vic", "viewer"), ("erin", "engineer")):
                add_user(tmp_path / "users.toml", name, role, PASSWORDS[name], CHEAP)
        (tmp_path / "station.toml").write_text(station_text)
        self.sf = load_station_file(tmp_path / "station.toml")
        self.now = time.time()
        self.stations = Station(self.sf, clock=lambda: self.now, wall=lambda: self.now)  # rx times too (trips)
        web_users = Users(self.sf.web.users, ph=CHEAP) if self.sf.web.users else Users(None, ph=CHEAP)
        self.attached = attach(self.stations, self.sf.web, users=web_users)
        self.client = starlette_testclient.TestClient(self.attached.app)
        self.seq = {"north": 0, "south": 0}
        self.stations.step()

    def frame(self, hoist: str = "north", ropes=((5000, 4900, 5100, 20000),) * 3 + ((5000, 4900, 5100, 20000),),
              dt: float = 0.1, step: bool = True, **kw) -> None:
        self.now += dt
        self.seq[hoist] += 1
        key = KEY_N if hoist == "north" else KEY_S
        wire = encode_frame(node=1, seq=self.seq[hoist], key=key, time_ms=self.seq[hoist] * 100, ropes=list(ropes),
                            battery_mv=12_000, depth_mm=kw.pop("depth_mm", 250_000), speed_mm_s=kw.pop("speed_mm_s", 0),
                            **kw)[1]
        self.stations.hoists[hoist].pipeline.feed("pithead", wire)
        if step:
            self.stations.step()

    def login(self, name: str) -> str:
        """Log in; returns the session's CSRF token."""
        page = self.client.get("/login")
        token = csrf_of(page.text)
        r = self.client.post("/login", data={"csrf": token, "name": name, "password": PASSWORDS[name], "next": "/"},
                             follow_redirects=False)
        assert r.status_code == 303, r.text
        return csrf_of(self.client.get("/hoist/north").text)

    def act(self, path: str, data: dict, client=None, **kw):
        """POST an action that reaches the station (`pumped`)."""
        return pumped(self, lambda: (client or self.client).post(path, data=data, **kw))

    def close(self) -> None:
        self.client.close()
        for r in self.attached.ctx.readers.values():
            r.close()
        self.stations.close()


def pumped(site: Site, send):
    """`send()` (a request whose action reaches the station) made from another thread while the
    station's thread (the test's) pumps: the face answers once the station has carried it out."""
    with concurrent.futures.ThreadPoolExecutor(1) as ex:
        fut = ex.submit(send)
        while not fut.done():
            for h in site.stations.hoists.values():
                h.pipeline.pump()
            time.sleep(0.005)
        return fut.result()


def csrf_of(html: str) -> str:
    m = re.search(r'data-csrf="([^"]+)"', html)
    assert m, html[:500]
    return m.group(1)


@pytest.fixture
def site(tmp_path):
    s = Site(tmp_path)
    yield s
    s.close()


DEVIATING = ((5000, 4900, 5100, 20000),) * 3 + ((6500, 6400, 6600, 26000),)   # rope 4 +21 % from the mean


def raise_deviation(site: Site) -> str:
    for _ in range(10):
        site.frame(ropes=DEVIATING)
    ids = [a["id"] for a in site.attached.ctx.listeners["north"].snapshot()["alarms"]["active"]]
    assert "deviation:n1:r3" in ids, ids
    return "deviation:n1:r3"


# -- pages ----------------------------------------------------------------------------------------


def test_pages_render_for_a_station_fed_frames(site):
    for _ in range(5):
        site.frame()
    site.frame(hoist="south")
    c = site.client
    r = c.get("/")
    assert r.status_code == 200
    assert 'data-hoist="north"' in r.text and 'data-hoist="south"' in r.text and "North shaft" in r.text
    r = c.get("/hoist/north")
    assert r.status_code == 200
    html = r.text
    assert 'id="node-1"' in html and 'id="conn"' in html and 'id="sound-banner"' in html
    for rope in (1, 2, 3, 4):
        assert f'data-rope="{rope}"' in html
    assert 'data-field="comp">50.0' in html                      # 5000 daN -> 50.0 kN
    assert 'data-field="devbar" data-dev="0.0"' in html
    assert 'data-field="stale"' in html and "/static/uplot/uPlot.iife.min.js" in html
    assert "cdn" not in html.lower()
    assert c.get("/hoist/north/trends").status_code == 200
    assert c.get("/hoist/north/log").status_code == 200
    assert c.get("/hoist/north/trips").status_code == 200
    assert c.get("/hoist/nowhere").status_code == 404
    snap = c.get("/hoist/north/snapshot.json").json()
    assert snap["nodes"]["1"]["ropes"][0]["comp_kN"] == pytest.approx(50.0, abs=0.01)
    assert snap["nodes"]["1"]["sum_kN"] == pytest.approx(200.0, abs=0.05)
    assert len(snap["trend"]["1"]["t"]) == 5
    site.frame(dt=10.0)                                     # ten seconds without a frame: a gap in the trend
    tr = c.get("/hoist/north/snapshot.json").json()["trend"]["1"]
    assert len(tr["t"]) == 7 and tr["ropes"][0][5] is None and tr["ropes"][0][6] == pytest.approx(50.0)
    r = c.get("/static/app.js")
    assert r.status_code == 200 and "EventSource" in r.text
    assert "default-src 'self'" in r.headers["content-security-policy"]


def test_a_status_only_or_faulted_rope_is_shown_as_such(site):
    ropes = ((5000, 4900, 5100, 20000),) * 3 + ((L.TENSION_ABSENT, L.TENSION_ABSENT, L.TENSION_ABSENT,
                                                 L.RAW_KPA_ABSENT),)
    site.frame(ropes=ropes)
    v = site.attached.ctx.listeners["north"].snapshot()["nodes"]["1"]
    assert v["partial"] and v["missing"] == [4] and v["ropes"][3]["fault"] and v["load_frac"] is None
    assert "PARTIAL SUM: rope 4 missing" in site.client.get("/hoist/north").text


def test_the_pistons_and_the_hoist_status_in_the_snapshot_and_the_page(site):
    ropes = [(5000, 4900, 5100, 20000, p) for p in (0, 123, -456, L.POS_ABSENT)]
    site.frame(ropes=ropes, stroke_mask=1 << 6, status=L.ST_STROKE_LIMIT)   # rope 3 near its extended end
    snap = site.attached.ctx.listeners["north"].snapshot()
    v = snap["nodes"]["1"]
    assert v["positions"] and [r["pos_mm"] for r in v["ropes"]] == [0.0, 12.3, -45.6, None]
    assert [(r["near_lo"], r["near_hi"]) for r in v["ropes"]] == [(False, False)] * 2 + [(False, True), (False, False)]
    assert snap["site"]["stroke_mm"] and len(snap["site"]["stroke_mm"]) == 4 and snap["site"]["margin_mm"] > 0
    html = site.client.get("/hoist/north").text
    assert 'class="node panel" id="node-1"' in html            # not "no-pos": the cylinders are shown
    assert html.count('<svg class="cyl"') == 4 + 1               # one per rope, and the row template's
    assert 'data-pos="12.3"' in html and "+12.3 mm" in html and 'data-field="hoist-status"' in html
    # the hoist's standing status (the imbalance the seals can hide) is status, not an alarm
    st = snap["alarms"]["hoist"]["1"]
    assert st["text"] and 0 < st["hidden_frac"] < 1
    assert not any("hidden" in a["kind"] for a in snap["alarms"]["active"])
    site.frame(ropes=[r[:4] for r in ropes], version=2)        # a version 2 node: no positions, no cylinders
    v = site.attached.ctx.listeners["north"].snapshot()["nodes"]["1"]
    assert not v["positions"] and all(r["pos_mm"] is None for r in v["ropes"])
    assert 'class="node panel no-pos" id="node-1"' in site.client.get("/hoist/north").text


# -- the live stream ------------------------------------------------------------------------------


def _events(lines):
    """(event, data) pairs from an SSE line iterator."""
    ev = None
    for line in lines:
        if line.startswith("event: "):
            ev = line[7:]
        elif line.startswith("data: ") and ev:
            yield ev, json.loads(line[6:])
            ev = None


def test_the_stream_sends_a_snapshot_then_a_delta_for_a_new_frame(site):
    site.frame()
    with site.client.stream("GET", "/hoist/north/stream") as r:
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream")
        events = _events(r.iter_lines())
        ev, snap = next(events)
        assert ev == "snapshot" and snap["hoist"] == "north" and snap["nodes"]["1"]["seq"] == 1
        assert "active" in snap["alarms"] and snap["site"]["imbalance_frac"] == pytest.approx(0.10)
        site.frame(ropes=DEVIATING, step=False)        # the station's thread: pump only (no tick)
        site.stations.hoists["north"].pipeline.pump()
        for ev, data in events:
            if ev == "frame":
                break
        assert data["seq"] == 2 and data["ropes"][3]["dev"] > 0.15


def test_a_reconnect_gets_the_alarm_state_again(site):
    aid = raise_deviation(site)
    for _ in range(2):                                   # connect, drop, connect again
        with site.client.stream("GET", "/hoist/north/stream") as r:
            ev, snap = next(_events(r.iter_lines()))
            assert ev == "snapshot"
            assert aid in [a["id"] for a in snap["alarms"]["active"]]
    assert site.attached.ctx.listeners["north"].subscribers() == 0


def test_a_slow_client_is_dropped_not_waited_for(site):
    import asyncio

    from ropemon.station.web.state import Subscriber
    lst = site.attached.ctx.listeners["north"]
    loop = asyncio.new_event_loop()
    try:
        sub = Subscriber(loop, maxsize=3)
        lst.subscribe(sub)
        for _ in range(10):
            site.frame()                                  # never blocks: the loop is not even running
        loop.run_until_complete(asyncio.sleep(0))        # deliver what was handed over
        assert sub.dropped and sub.queue.get_nowait() is None
        site.frame()
        assert sub not in lst._subs
    finally:
        loop.close()


def test_the_overview_stream_has_every_hoist(site):
    site.frame()
    with site.client.stream("GET", "/overview/stream") as r:
        ev, data = next(_events(r.iter_lines()))
    assert ev == "overview" and [s["hoist"] for s in data] == ["north", "south"]
    assert data[0]["nodes"]["1"]["sum_kN"] > 0 and data[1]["nodes"] == {}


# -- actions and who may do them --------------------------------------------------------------------


def test_ack_without_login_is_refused(site):
    aid = raise_deviation(site)
    token = csrf_of(site.client.get("/hoist/north").text)
    r = site.client.post("/hoist/north/ack", data={"csrf": token, "alarm": aid}, follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"].startswith("/login")
    r = site.client.post("/hoist/north/ack", data={"csrf": token, "alarm": aid}, headers={"X-Requested-With": "fetch"})
    assert r.status_code == 401
    site.stations.step()
    assert [a.latched for a in site.stations.hoists["north"].alarms.engine.active() if a.id == aid] == [True]


def test_an_operator_acknowledges_and_the_log_says_who(site, tmp_path):
    aid = raise_deviation(site)
    token = site.login("olga")
    page = site.client.get("/hoist/north").text
    assert f'data-alarm-id="{aid}"' in page and 'class="ack"' in page and 'id="ack-all"' in page
    assert 'id="ack-all-form">' in page                  # shown while an alarm awaits acknowledgement
    r = site.act("/hoist/north/ack", {"csrf": token, "alarm": aid}, headers={"X-Requested-With": "fetch"})
    assert r.status_code == 200 and r.json() == {"ok": True, "done": f"acknowledged {aid}"}, r.text
    site.stations.step()                                  # carried out on the station's thread (above)
    (alarm,) = [a for a in site.stations.hoists["north"].alarms.engine.active() if a.id == aid]
    assert not alarm.latched and alarm.acked_by == "olga (web)"
    with Store(tmp_path / "data" / "north.db", readonly=True) as st:
        acks = [e for e in st.events() if e["action"] == "ack"]
    assert [(e["alarm"], e["operator"]) for e in acks] == [(aid, "olga (web)")]
    log = site.client.get("/hoist/north/log", params={"action": "ack"}).text
    assert "olga (web)" in log and 'data-action="ack"' in log


def test_a_form_post_acknowledges_all_and_redirects_back(site):
    raise_deviation(site)
    token = site.login("olga")
    r = site.act("/hoist/north/ack", {"csrf": token, "alarm": "*"}, follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/hoist/north"
    site.stations.step()
    assert not [a for a in site.stations.hoists["north"].alarms.engine.active() if a.latched]
    page = site.client.get("/hoist/north").text
    assert "acknowledged all alarms" in page
    assert 'id="ack-all-form" hidden' in page          # nothing left to acknowledge: no button


def test_a_viewer_cannot_acknowledge(site):
    aid = raise_deviation(site)
    token = site.login("vic")
    assert 'class="ack"' not in site.client.get("/hoist/north").text
    r = site.client.post("/hoist/north/ack", data={"csrf": token, "alarm": aid}, headers={"X-Requested-With": "fetch"})
    assert r.status_code == 403 and "viewer" in r.json()["error"]


def test_an_action_without_the_csrf_token_is_refused(site):
    aid = raise_deviation(site)
    site.login("olga")
    for data in ({"alarm": aid}, {"alarm": aid, "csrf": "not-the-token"}):
        r = site.client.post("/hoist/north/ack", data=data, headers={"X-Requested-With": "fetch"})
        assert r.status_code == 403 and r.json()["field"] == "csrf"
    r = site.client.post("/login", data={"name": "olga", "password": PASSWORDS["olga"]}, follow_redirects=False)
    assert r.status_code == 403                            # the login form carries the token too


def test_shelve_with_reason_and_minutes(site):
    aid = raise_deviation(site)
    token = site.login("olga")
    h = {"X-Requested-With": "fetch"}
    post = site.client.post
    for data, fld in (({"alarm": aid, "minutes": "30"}, "reason"),
                      ({"alarm": aid, "minutes": "30", "reason": "x"}, "reason"),
                      ({"alarm": aid, "minutes": "0", "reason": "rope change"}, "minutes"),
                      ({"alarm": aid, "minutes": "1e9", "reason": "rope change"}, "minutes"),
                      ({"alarm": aid, "minutes": "nan", "reason": "rope change"}, "minutes"),
                      ({"alarm": "deviation:n9:r0", "minutes": "30", "reason": "rope change"}, "alarm"),
                      ({"alarm": "<script>", "minutes": "30", "reason": "rope change"}, "alarm")):
        r = post("/hoist/north/shelve", data={"csrf": token, **data}, headers=h)
        assert r.status_code == 400 and r.json()["field"] == fld, (data, r.text)
    r = site.act("/hoist/north/shelve", {"csrf": token, "alarm": aid, "minutes": "30", "reason": "rope change"},
                 headers=h)
    assert r.status_code == 200 and r.json()["ok"]
    site.stations.step()
    eng = site.stations.hoists["north"].alarms.engine
    (hidden,) = [a for a in eng.hidden() if a.id == aid]
    assert hidden.state == "shelved" and "rope change (olga (web))" in hidden.note
    assert hidden.shelved_until == pytest.approx(site.now + 30 * 60, abs=1.0)
    page = site.client.get("/hoist/north").text
    assert f'class="hidden-alarm" data-alarm-id="{aid}"' in page
    r = site.act("/hoist/north/unshelve", {"csrf": token, "alarm": aid}, headers=h)
    assert r.status_code == 200
    site.stations.step()
    assert aid in [a.id for a in eng.active()]


def test_out_of_service_needs_an_engineer(site):
    aid = raise_deviation(site)
    token = site.login("olga")
    r = site.client.post("/hoist/north/remove", data={"csrf": token, "alarm": aid, "reason": "transmitter swap"},
                         headers={"X-Requested-With": "fetch"})
    assert r.status_code == 403
    site.client.post("/logout", data={"csrf": token})
    token = site.login("erin")
    r = site.act("/hoist/north/remove", {"csrf": token, "alarm": aid, "reason": "transmitter swap"},
                 headers={"X-Requested-With": "fetch"})
    assert r.status_code == 200, r.text
    site.stations.step()
    assert [a.state for a in site.stations.hoists["north"].alarms.engine.hidden()] == ["out_of_service"]


def test_a_refused_command_is_its_senders_response_and_not_another_faces(site, monkeypatch):
    """The station refuses a shelve (here its engine refuses every one): the web's response says
    so (409, the reason; a form post's flash); another face's refused command (OPC UA's) is not
    taken for the web's: the web's next action is answered as carried out."""
    from ropemon.station.pipeline import Shelve
    aid = raise_deviation(site)
    token = site.login("olga")
    h = {"X-Requested-With": "fetch"}

    def refuse(*args, **kw):
        raise ValueError("shelving refused by the test")
    monkeypatch.setattr(site.stations.hoists["north"].alarms.engine, "shelve", refuse)
    shelve = {"csrf": token, "alarm": aid, "minutes": "30", "reason": "rope change"}
    r = site.act("/hoist/north/shelve", shelve, headers=h)
    assert r.status_code == 409 and r.json() == {"ok": False, "refused": True, "error": "shelving refused by the test"}
    r = site.act("/hoist/north/shelve", shelve, follow_redirects=False)
    assert r.status_code == 303
    assert "refused: shelving refused by the test" in site.client.get("/hoist/north").text
    other = site.stations.submit("north", Shelve("alice", "opcua", alarm=aid, minutes=5, reason="rope change"))
    site.stations.step()
    assert not other.result(timeout=0).ok
    r = site.act("/hoist/north/ack", {"csrf": token, "alarm": aid}, headers=h)
    assert r.status_code == 200 and r.json() == {"ok": True, "done": f"acknowledged {aid}"}
    site.stations.hoists["north"].store.commit()
    with Store(site.stations.hoists["north"].db_path, readonly=True) as st:
        refused = [e["operator"] for e in st.events() if e["action"] == "refused"]
    assert refused == ["olga (web)", "olga (web)", "alice (opcua)"]


def test_an_action_the_station_does_not_answer_in_time_is_sent_as_pending(site, monkeypatch):
    from ropemon.station import commands
    aid = raise_deviation(site)
    token = site.login("olga")
    monkeypatch.setattr(commands, "OUTCOME_WAIT_S", 0.05)
    r = site.client.post("/hoist/north/ack", data={"csrf": token, "alarm": aid}, headers={"X-Requested-With": "fetch"})
    assert r.status_code == 200 and r.json()["pending"] is True and "not answered yet" in r.json()["done"]
    site.stations.step()                                  # carried out at the station's next pump all the same
    (alarm,) = [a for a in site.stations.hoists["north"].alarms.engine.active() if a.id == aid]
    assert not alarm.latched


def test_accept_rewound_only_for_a_refused_node(site):
    token = site.login("olga")
    r = site.client.post("/hoist/north/accept-rewound", data={"csrf": token, "node": "1"},
                         headers={"X-Requested-With": "fetch"})
    assert r.status_code == 400 and r.json()["field"] == "node"


def test_login_is_refused_with_a_wrong_password_and_throttled(site, caplog):
    caplog.set_level("INFO", logger="ropemon.web.audit")
    c = site.client
    token = csrf_of(c.get("/login").text)
    for _ in range(accounts.LOGIN_FAILS):
        r = c.post("/login", data={"csrf": token, "name": "olga", "password": "wrong password"})
        assert r.status_code == 401 and "wrong name or password" in r.text
    r = c.post("/login", data={"csrf": token, "name": "olga", "password": PASSWORDS["olga"]})
    assert r.status_code == 401 and "too many failed logins" in r.text
    r = c.post("/login", data={"csrf": token, "name": "nobody", "password": "whatever it is"})
    assert r.status_code == 401
    refused = [r.getMessage() for r in caplog.records if r.name == "ropemon.web.audit"]
    assert len(refused) == accounts.LOGIN_FAILS + 2 and all(m.startswith("login refused: ") for m in refused)
    assert "'olga' from testclient: too many failed logins" in refused[-2] and "'nobody'" in refused[-1]


def test_logins_and_logouts_are_in_the_audit_log(site, caplog):
    caplog.set_level("INFO", logger="ropemon.web.audit")
    token = site.login("olga")
    site.client.post("/logout", data={"csrf": token}, follow_redirects=False)
    assert [r.getMessage() for r in caplog.records if r.name == "ropemon.web.audit"] == [
        "login: olga (operator) from testclient", "logout: olga from testclient"]


def test_viewing_can_need_a_login(tmp_path):
    s = Site(tmp_path, STATION + "view_without_login = false\n")
    try:
        r = s.client.get("/hoist/north", follow_redirects=False)
        assert r.status_code == 303 and r.headers["location"] == "/login?next=/hoist/north"
        assert s.client.get("/hoist/north/stream").status_code == 401
        assert s.client.get("/hoist/north/snapshot.json").status_code == 401
        s.login("vic")
        assert s.client.get("/hoist/north").status_code == 200
    finally:
        s.close()


# -- the users file -----------------------------------------------------------------------------------


def test_no_user_is_shipped(tmp_path):
    s = Site(tmp_path, STATION.replace('users = "users.toml"\n', ""), users=False)
    try:
        assert s.attached.ctx.users.all() == {}
        page = s.client.get("/login").text
        assert "No users are set up" in page
        token = csrf_of(page)
        for name in ("admin", "operator", "root", "ropemon"):
            r = s.client.post("/login", data={"csrf": token, "name": name, "password": "admin"})
            assert r.status_code == 401
    finally:
        s.close()


def test_the_users_file_is_written_0600_with_argon2id_hashes(tmp_path):
    p = tmp_path / "users.toml"
    add_user(p, "olga", "operator", "a long password", CHEAP)
    assert stat.S_IMODE(os.stat(p).st_mode) == 0o600
    text = p.read_text()
    assert "a long password" not in text and "$argon2id$" in text
    users = load_users(p)
    assert users["olga"].role == "operator" and users["olga"].may("ack") and not users["olga"].may("remove")
    add_user(p, "olga", "engineer", "another long password", CHEAP)    # replaced, not doubled
    assert load_users(p)["olga"].role == "engineer"
    with pytest.raises(UsersError, match="password: at least"):
        add_user(p, "kim", "operator", "short", CHEAP)
    with pytest.raises(UsersError, match="role"):
        add_user(p, "kim", "admin", "a long password", CHEAP)
    with pytest.raises(UsersError, match="name"):
        add_user(p, "Kim Smith", "operator", "a long password", CHEAP)


@pytest.mark.parametrize("text, field", [
    ('[user.olga]\nrole = "boss"\npassword = "HASH"\n', "user.olga.role"),
    ('[user.olga]\nrole = "operator"\npassword = "plain text"\n', "user.olga.password"),
    ('[user.olga]\nrole = "operator"\npassword = "$argon2id$v=19$garbage"\n', "user.olga.password"),
    ('[user.olga]\nrole = "operator"\n', "user.olga.password"),
    ('[user.olga]\nrole = "operator"\npassword = "HASH"\nadmin = true\n', "admin"),
    ('[user."Olga Smith"]\nrole = "operator"\npassword = "HASH"\n', "user.Olga Smith"),
    ('[users.olga]\nrole = "operator"\npassword = "HASH"\n', "users"),
    ("[user.olga\n", "not valid TOML"),
])
def test_bad_users_files_are_refused_with_the_field(tmp_path, text, field):
    p = tmp_path / "users.toml"
    p.write_text(text.replace("HASH", CHEAP.hash("a long password")))
    p.chmod(0o600)
    with pytest.raises(UsersError) as e:
        load_users(p)
    assert field in str(e.value) and str(p) in str(e.value), str(e.value)


def test_a_users_file_readable_by_others_is_refused(tmp_path):
    p = tmp_path / "users.toml"
    add_user(p, "olga", "operator", "a long password", CHEAP)
    p.chmod(0o644)
    with pytest.raises(UsersError, match="chmod 600"):
        load_users(p)
    sf_text = STATION
    (tmp_path / "north.json").write_text(json.dumps(make_node_json(example_physical(), node_id=1, key=KEY_N)))
    (tmp_path / "south.json").write_text(json.dumps(make_node_json(example_physical(), node_id=1, key=KEY_S)))
    (tmp_path / "station.toml").write_text(sf_text)
    sf = load_station_file(tmp_path / "station.toml")
    stations = Station(sf)
    try:
        with pytest.raises(WebError, match="users.toml"):
            attach(stations, sf.web)
    finally:
        stations.close()


def test_the_session_secret_is_made_owner_only(tmp_path):
    p = tmp_path / "secret"
    first = auth.load_secret(p)
    assert stat.S_IMODE(os.stat(p).st_mode) == 0o600 and auth.load_secret(p) == first
    p.chmod(0o644)
    with pytest.raises(UsersError, match="chmod 600"):
        auth.load_secret(p)


def test_a_user_removed_from_the_file_loses_the_session_rights(site, tmp_path):
    aid = raise_deviation(site)
    token = site.login("olga")
    accounts.remove_user(tmp_path / "users.toml", "olga")
    r = site.client.post("/hoist/north/ack", data={"csrf": token, "alarm": aid}, headers={"X-Requested-With": "fetch"})
    assert r.status_code == 401


# -- trends, log and trips from the store ---------------------------------------------------------------


def test_history_trips_and_csv_from_the_log(site):
    def at(pos_01mm):              # every rope's tension as the default frame's, its piston at pos_01mm
        return [(5000, 4900, 5100, 20000, pos_01mm + 10 * i) for i in range(4)]

    for _ in range(40):                                    # at the bottom, resting
        site.frame(depth_mm=60_000, speed_mm_s=0, ropes=at(12))
    for k in range(120):                                   # a wind up at 4 m/s: 48 m
        site.frame(depth_mm=60_000 - k * 400, speed_mm_s=-4000, ropes=at(12))
    for _ in range(60):                                    # at the pithead, resting
        site.frame(depth_mm=12_000, speed_mm_s=0, ropes=at(-25))
    site.stations.hoists["north"].store.commit()          # what the reader sees: committed frames
    c = site.client
    h = c.get("/hoist/north/history.json", params={"node": 1, "hours": 1}).json()
    assert h["frames"] == 220 and len(h["ropes"]) == 4 and h["ropes"][0][0] == pytest.approx(50.0, abs=0.01)
    site.now += 600                                        # ten minutes without a frame, then one
    site.frame(depth_mm=12_000)
    site.stations.hoists["north"].store.commit()
    g = c.get("/hoist/north/history.json", params={"node": 1, "hours": 1}).json()
    assert g["frames"] == 221 and g["ropes"][0][-2] is None and g["ropes"][0][-1] == pytest.approx(50.0)
    assert c.get("/hoist/north/history.json", params={"node": 1, "hours": "-1"}).status_code == 400
    assert c.get("/hoist/north/history.json", params={"node": "x"}).json()["field"] == "node"
    page = c.get("/hoist/north/trips").text
    ids = re.findall(r'data-trip-id="(\d+)"', page)
    assert ids, page
    trip = c.get(f"/hoist/north/trips/{ids[0]}")
    assert trip.status_code == 200 and 'id="trip-rests"' in trip.text and "rope 4" in trip.text
    csv_text = c.get(f"/hoist/north/trips/{ids[0]}.csv").text
    head, first = csv_text.splitlines()[:2]
    assert head.startswith("rx_time,rx_time_utc,node_time_s,depth_m") and "rope4_raw_kN" in head
    assert head.endswith("rope4_pos_mm") and first.endswith(",1.200,2.200,3.200,4.200")
    pistons = re.search(r'<table id="trip-pistons".*?</table>', trip.text, re.S).group(0)
    row2 = re.search(r'<tr data-row="rope 2">(.*?)</tr>', pistons, re.S).group(1)
    assert re.findall(r"<td>([^<]*)</td>", row2) == ["+2.2", "-1.5"]   # where it left, where it arrived
    series = c.get(f"/hoist/north/trips/{ids[0]}.json").json()
    assert len(series["comp"]) == 4 and len(series["t"]) == len(csv_text.splitlines()) - 1
    assert c.get("/hoist/north/trips/999999").status_code == 404
    assert c.get("/hoist/north/trips/abc").status_code == 400


def test_the_event_log_filters(site):
    raise_deviation(site)
    c = site.client
    page = c.get("/hoist/north/log", params={"kind": "deviation"}).text
    kinds = re.findall(r'data-event-id="\d+" data-action="(\w+)"', page)
    assert kinds and set(kinds) <= {"raise"}
    assert 'data-event-id' not in c.get("/hoist/north/log", params={"text": "no such text at all"}).text
    assert c.get("/hoist/north/log", params={"action": "explode"}).status_code == 400
    assert c.get("/hoist/north/log", params={"node": "999"}).status_code == 400


def test_the_vendored_uplot_is_node_modules_copy():
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]
    dist = root / "node_modules" / "uplot"
    if not dist.is_dir():
        pytest.skip("node_modules/uplot not installed (npm ci)")
    ours = root / "host" / "ropemon" / "station" / "web" / "static" / "uplot"
    for name, theirs in (("uPlot.iife.min.js", dist / "dist" / "uPlot.iife.min.js"),
                         ("uPlot.min.css", dist / "dist" / "uPlot.min.css"), ("LICENSE", dist / "LICENSE")):
        assert (ours / name).read_bytes() == theirs.read_bytes(), name
    lock = json.loads((root / "package-lock.json").read_text())
    assert lock["packages"]["node_modules/uplot"]["version"] == json.loads((dist / "package.json").read_text())["version"]


def test_ropemon_user_add_reads_the_password_from_stdin_and_refuses_a_short_one(tmp_path):
    import subprocess
    import sys
    p = tmp_path / "users.toml"
    run = lambda args, stdin: subprocess.run([sys.executable, "-m", "ropemon.cli", "user", *args],  # noqa: E731
                                             input=stdin, capture_output=True, text=True, timeout=60)
    r = run(["add", str(p), "olga", "--role", "operator", "--password-stdin"], "a long password\n")
    assert r.returncode == 0, r.stderr
    assert stat.S_IMODE(os.stat(p).st_mode) == 0o600
    u = load_users(p)["olga"]
    assert u.role == "operator" and PasswordHasher().verify(u.password, "a long password")
    r = run(["add", str(p), "kim", "--role", "operator", "--password-stdin"], "short\n")
    assert r.returncode == 2 and "at least 8" in r.stderr
    r = run(["add", str(p), "kim", "--role", "operator"], "")            # no terminal to ask twice
    assert r.returncode == 2 and "--password-stdin" in r.stderr
    r = run(["list", str(p)], "")
    assert r.stdout.split() == ["olga", "operator"]
    assert run(["remove", str(p), "olga"], "").returncode == 0 and load_users(p) == {}


def test_the_face_serves_over_http_and_says_where_and_refuses_a_busy_port(tmp_path):
    """`start` (the faces contract): uvicorn in its own thread on the configured address."""
    import dataclasses
    import socket
    import urllib.request

    from ropemon.station.web import server

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    node_json(tmp_path, "north.json", 1, KEY_N)
    node_json(tmp_path, "south.json", 1, KEY_S)
    (tmp_path / "station.toml").write_text(STATION.replace('users = "users.toml"\n', "") + f"port = {port}\n")
    sf = load_station_file(tmp_path / "station.toml")
    stations = Station(sf)
    face = server.start(stations, sf.web)
    try:
        assert face.describe().startswith(f"web: http://127.0.0.1:{port}/ (2 hoists; view without login; no users")
        stations.step()
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/hoist/north", timeout=10) as r:
            assert r.status == 200 and b'id="conn"' in r.read()
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/hoist/north/stream", timeout=10) as r:
            assert r.headers["content-type"].startswith("text/event-stream")
            assert r.readline() == b"retry: 2000\n" and r.readline() == b"event: snapshot\n"
        other = Station(sf)
        try:
            with pytest.raises(WebError, match=f"cannot listen on 127.0.0.1:{port}"):
                server.start(other, dataclasses.replace(sf.web, secret=None))
        finally:
            other.close()
    finally:
        face.stop()
        stations.close()
    assert not face.thread.is_alive()


def test_the_hoist_status_goes_out_at_once_when_it_comes_then_at_most_once_a_second():
    from types import SimpleNamespace

    from ropemon.station.alarms import HoistStatus
    from ropemon.station.nodefigures import NodeFigures
    from ropemon.station.pipeline import AlarmState
    from ropemon.station.web.state import WebListener

    lst = WebListener(SimpleNamespace(id="h", name="H", figures=NodeFigures([0.01] * 4)))
    sent: list[tuple[float, str, str]] = []
    lst._broadcast = lambda event, data: sent.append((lst.now, event, data))   # type: ignore[method-assign]

    def state(t, kn):
        if kn is None:
            return AlarmState(t, (), {}, (), {})
        st = HoistStatus(1, 0.03, kn * 1000, 0.10, True, f"the seals can hide 3.0% at {kn:.1f} kN per rope")
        return AlarmState(t, (), {}, (), {1: st})

    lst.on_alarms(state(0.0, None))
    for k in range(1, 31):                      # 4 ticks a second for 7.5 s, the rope tension changing each
        lst.on_alarms(state(k * 0.25, 40.0 + k))
    hoist = [(t, json.loads(d)) for t, ev, d in sent if ev == "hoist"]
    assert hoist[0] == (0.0, {}) and hoist[1][0] == 0.25           # the status came: at once
    assert all(b[0] - a[0] >= 1.0 for a, b in zip(hoist[1:], hoist[2:]))
    assert 7 <= len(hoist) <= 9
    assert lst.snapshot()["alarms"]["hoist"] == hoist[-1][1]
    assert hoist[-1][1]["1"]["hidden_frac"] == 0.03


def test_frame_view_marks_the_held_back_ropes_with_the_reason():
    """The web's frame view: each rope's `held_back` from status bits 11-14, the ropes listed
    and the reason once; the bits are not shown again among the node's flags."""
    from ropemon.station.protocol import L as layout
    from ropemon.station.protocol import Rope, decode_raw, encode_frame
    from ropemon.station.views import HELD_BACK_WHY
    from ropemon.station.web.state import frame_view

    rs = [Rope(4600, 4500, 4700, 1300, 0)] * 4
    raw, _ = encode_frame(node=1, seq=1, ropes=rs, status=(1 << layout.ST_HELD_BACK_SHIFT) | layout.ST_BATTERY_LOW)
    v = frame_view(decode_raw(raw), 1.0, [0.03] * 4, 320_000.0, None)
    assert [r["held_back"] for r in v["ropes"]] == [True, False, False, False]
    assert v["held_back"] == [1] and v["held_why"] == HELD_BACK_WHY
    assert "held_back" not in v["flags"] and "battery_low" in v["flags"]
    raw, _ = encode_frame(node=1, seq=2, ropes=rs)
    v = frame_view(decode_raw(raw), 1.0, [0.03] * 4, 320_000.0, None)
    assert v["held_back"] == [] and v["held_why"] == "" and not any(r["held_back"] for r in v["ropes"])
