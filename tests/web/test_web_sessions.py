"""The web face's sessions end, and its logins are throttled per client address (ropemon.station.web.auth, ropemon.station.users).

A cookie copied from a logged-in browser is worth nothing once the user logs out, changes the
password (from another process, as `ropemon user passwd` does) or changes role, or once the
session has been idle for web.session_idle_min. A name locked after failed logins from one
address can still log in from another. Through Starlette's TestClient on the Site of test_web.
"""
from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest
from argon2 import PasswordHasher

starlette_testclient = pytest.importorskip("starlette.testclient")
from test_web import CHEAP, PASSWORDS, STATION, Site, csrf_of, raise_deviation  # noqa: E402

from ropemon.station.stationfile import StationConfigError, load_station_file  # noqa: E402
from ropemon.station import users as accounts  # noqa: E402


@pytest.fixture
def site(tmp_path):
    s = Site(tmp_path)
    yield s
    s.close()


def _copy(site: Site, client=("testclient", 50000)):
    """A second browser holding a copy of the first one's cookie."""
    other = starlette_testclient.TestClient(site.attached.app, client=client)
    other.cookies.update(site.client.cookies)
    return other


def _ack(site: Site, client, token: str, alarm: str) -> int:
    return site.act("/hoist/north/ack", {"csrf": token, "alarm": alarm}, client=client,
                    headers={"X-Requested-With": "fetch"}).status_code


def test_a_copied_cookie_is_refused_after_logout(site):
    aid = raise_deviation(site)
    token = site.login("olga")
    thief = _copy(site)
    assert _ack(site, thief, token, aid) == 200                 # the copy works while the session lives
    second = _copy(site)                                   # another screen logged in as olga too
    second.cookies.clear()
    t2 = csrf_of(second.get("/login").text)
    assert second.post("/login", data={"csrf": t2, "name": "olga", "password": PASSWORDS["olga"]},
                       follow_redirects=False).status_code == 303
    t2 = csrf_of(second.get("/hoist/north").text)
    site.client.post("/logout", data={"csrf": token}, follow_redirects=False)
    assert _ack(site, thief, token, aid) == 401
    assert _ack(site, second, t2, aid) == 401                   # logout ends every session of the user
    page = thief.get("/hoist/north").text
    assert 'data-user=""' in page and 'id="logout"' not in page
    thief.close()
    second.close()


def test_a_copied_cookie_is_refused_after_a_password_change_by_ropemon_user_passwd(site, tmp_path):
    aid = raise_deviation(site)
    token = site.login("olga")
    thief = _copy(site)
    assert _ack(site, thief, token, aid) == 200
    r = subprocess.run([sys.executable, "-m", "ropemon.cli", "user", "passwd", str(tmp_path / "users.toml"), "olga",
                        "--password-stdin"], input="olga's new long secret\n", capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    assert accounts.load_users(tmp_path / "users.toml")["olga"].role == "operator"      # the role kept
    assert _ack(site, thief, token, aid) == 401
    assert _ack(site, site.client, token, aid) == 401           # the session it was copied from too
    r = subprocess.run([sys.executable, "-m", "ropemon.cli", "user", "passwd", str(tmp_path / "users.toml"), "kim",
                        "--password-stdin"], input="a long password\n", capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and "no user 'kim'" in r.stderr
    PASSWORDS_NEW = dict(PASSWORDS, olga="olga's new long secret")
    t = csrf_of(site.client.get("/login").text)
    assert site.client.post("/login", data={"csrf": t, "name": "olga", "password": PASSWORDS["olga"]},
                            follow_redirects=False).status_code == 401
    assert site.client.post("/login", data={"csrf": t, "name": "olga", "password": PASSWORDS_NEW["olga"]},
                            follow_redirects=False).status_code == 303
    thief.close()


def test_a_copied_cookie_is_refused_after_a_role_change(site, tmp_path):
    aid = raise_deviation(site)
    token = site.login("olga")
    thief = _copy(site)
    assert _ack(site, thief, token, aid) == 200
    accounts.add_user(tmp_path / "users.toml", "olga", "engineer", PASSWORDS["olga"], CHEAP)   # up, not down
    assert _ack(site, thief, token, aid) == 401
    assert _ack(site, site.client, token, aid) == 401
    thief.close()


def test_an_idle_session_ends_and_use_keeps_it(tmp_path):
    s = Site(tmp_path, STATION + "session_idle_min = 2\n")
    try:
        assert s.sf.web.session_idle_min == 2.0
        now = [1000.0]
        s.attached.ctx.sessions.clock = lambda: now[0]
        aid = raise_deviation(s)
        token = s.login("olga")
        now[0] += 100
        assert s.client.get("/hoist/north").status_code == 200          # a page: the session is used
        now[0] += 100
        assert _ack(s, s.client, token, aid) == 200             # 200 s since login, 100 s idle
        now[0] += 110
        assert s.client.get("/hoist/north/snapshot.json").status_code == 200   # the page's own data: not use
        now[0] += 11
        assert _ack(s, s.client, token, aid) == 401             # 121 s idle
        assert _ack(s, s.client, token, aid) == 401
    finally:
        s.close()


@pytest.mark.parametrize("value", ["0", "0.5", "721", '"30"'])
def test_the_idle_time_is_range_checked(tmp_path, value):
    (tmp_path / "station.toml").write_text(STATION + f"session_idle_min = {value}\n")
    with pytest.raises(StationConfigError, match="web.session_idle_min"):
        load_station_file(tmp_path / "station.toml")


def _login(client, name: str, password: str) -> int:
    t = csrf_of(client.get("/login").text)
    return client.post("/login", data={"csrf": t, "name": name, "password": password},
                       follow_redirects=False).status_code


def test_a_name_locked_from_one_address_still_logs_in_from_another(site):
    a = starlette_testclient.TestClient(site.attached.app, client=("10.20.0.66", 40000))
    b = starlette_testclient.TestClient(site.attached.app, client=("10.20.0.7", 40001))
    try:
        for _ in range(accounts.LOGIN_FAILS):
            assert _login(a, "olga", "a wrong password") == 401
        r = a.post("/login", data={"csrf": csrf_of(a.get("/login").text), "name": "olga",
                                   "password": PASSWORDS["olga"]})
        assert r.status_code == 401 and "too many failed logins for this name" in r.text   # held from A
        assert _login(b, "olga", PASSWORDS["olga"]) == 303                                # not from B
        assert _login(a, "erin", PASSWORDS["erin"]) == 303                                # A: other names
    finally:
        a.close()
        b.close()


def test_an_address_failing_with_many_names_is_held_and_the_others_are_not(site):
    a = starlette_testclient.TestClient(site.attached.app, client=("10.20.0.66", 40000))
    b = starlette_testclient.TestClient(site.attached.app, client=("10.20.0.7", 40001))
    try:
        for i in range(accounts.ADDRESS_FAILS):
            assert _login(a, f"guess{i}", "a wrong password") == 401
        r = a.post("/login", data={"csrf": csrf_of(a.get("/login").text), "name": "olga",
                                   "password": PASSWORDS["olga"]})
        assert r.status_code == 401 and "too many failed logins from this address" in r.text
        assert _login(b, "olga", PASSWORDS["olga"]) == 303
    finally:
        a.close()
        b.close()


class _Gate(PasswordHasher):
    """A hasher whose checks wait for a gate: to fill the pool on purpose."""

    def __init__(self) -> None:
        super().__init__(time_cost=1, memory_cost=8, parallelism=1)
        self.gate, self.entered = threading.Event(), threading.Semaphore(0)

    def verify(self, hash, password):  # noqa: A002
        self.entered.release()
        self.gate.wait(10)
        return super().verify(hash, password)


def test_a_login_beyond_the_pool_is_refused_busy_429_and_unknown_names_use_the_pool(tmp_path):
    """One worker and no queue: while a check runs, another login (known or unknown name) is 429."""
    s = Site(tmp_path)
    gate = _Gate()
    users = s.attached.ctx.users
    users.ph, users.pool = gate, accounts.HashPool(workers=1, queue=0)
    users._dummy = gate.hash("whatever")
    try:
        first = threading.Thread(target=_login, args=(s.client, "nobody", "a wrong password"))
        first.start()                                        # an unknown name takes the one worker
        assert gate.entered.acquire(timeout=10)
        other = starlette_testclient.TestClient(s.attached.app, client=("10.20.0.7", 40001))
        r = other.post("/login", data={"csrf": csrf_of(other.get("/login").text), "name": "olga",
                                       "password": PASSWORDS["olga"]})
        assert r.status_code == 429 and r.headers["retry-after"] == "1" and "busy" in r.text
        gate.gate.set()
        first.join(10)
        assert users.pool.peak == 1 and users.pool.refused == 1
        assert _login(other, "olga", PASSWORDS["olga"]) == 303     # a busy refusal is not a failure
        other.close()
    finally:
        gate.gate.set()
        s.close()


def test_an_unknown_name_is_checked_against_a_hash_of_the_same_cost(tmp_path):
    users = accounts.Users(None)
    assert accounts.extract_parameters(users._dummy) == accounts.extract_parameters(accounts.hasher().hash("x" * 12))


def test_a_stream_that_needs_a_login_ends_with_its_session(tmp_path, monkeypatch):
    from ropemon.station.web import app
    monkeypatch.setattr(app, "STREAM_RECHECK_S", 0.0, raising=False)
    monkeypatch.setattr(app, "KEEPALIVE_S", 0.2)            # a line at least this often: no hang
    s = Site(tmp_path, STATION + "view_without_login = false\n")
    try:
        token = s.login("vic")
        other = _copy(s)
        with s.client.stream("GET", "/hoist/north/stream") as r:
            lines = r.iter_lines()
            assert next(lines) == "retry: 2000"
            assert other.post("/logout", data={"csrf": token}, follow_redirects=False).status_code == 303
            s.frame()                                    # the stream wakes, finds its session ended
            rest, ended, t_end = [], True, time.monotonic() + 5.0
            for line in lines:                           # and ends
                rest.append(line)
                if time.monotonic() > t_end:
                    ended = False
                    break
        assert ended and not any(line.startswith("event: frame") for line in rest), rest[-10:]
        assert "event: session_ended" in rest, rest[-10:]      # the page goes to the login form
        assert s.client.get("/hoist/north/stream").status_code == 401
        other.close()
    finally:
        s.close()
