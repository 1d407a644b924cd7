"""The web face's sessions and CSRF (who may do what, and the logins: ropemon.station.users).

Sessions (`Sessions`) are the station's, in memory: the session cookie (Starlette's
SessionMiddleware, signed with itsdangerous) carries only a random session id and the CSRF
token. A session holds the user's name and a stamp of the user's entry as it was at login
(role and password hash); at every request the entry is looked up in the users file (read
again when it changes, also when `ropemon user passwd` changes it from another process) and a
session whose user is gone, or whose role or password changed, is ended. Logging out ends
every session of that user; a session unused for web.session_idle_min ends; a restart of the
station ends them all. A cookie copied before any of these is worth nothing after.
Every action (POST) carries the token (form field `csrf` or header X-CSRF-Token), or is refused.
"""
from __future__ import annotations

import hmac
import os
import re
import secrets
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, MutableMapping

from ropemon.station import files
from ropemon.station.users import User, Users, UsersError, owner_only

MAX_SECRET = 4 * files.KB
DEFAULT_IDLE_MIN = 30.0                  # web.session_idle_min's default: a session unused this long ends
MAX_SESSIONS = 1000                      # sessions kept at most (the least recently used ends first)


def user_stamp(user: User) -> str:
    """What a session remembers of its user's entry: a change of role or password ends it."""
    return f"{user.role}\0{user.password}"


@dataclass
class LoginSession:
    name: str
    stamp: str
    seen: float       # the clock at its last use


class Sessions:
    """The station's login sessions, in memory, keyed by a random id (the cookie carries only the
    id): a session ends when its user logs out (every session of that user), when the user's
    entry is removed or its role or password changes, or after `idle_s` unused."""

    def __init__(self, users: Users, idle_s: float, clock: Any = time.monotonic, cap: int = MAX_SESSIONS) -> None:
        self.users, self.idle_s, self.clock, self.cap = users, idle_s, clock, cap
        self._lock = threading.Lock()
        self._s: dict[str, LoginSession] = {}

    def new(self, user: User) -> str:
        sid = secrets.token_urlsafe(32)
        now = self.clock()
        with self._lock:
            self._prune(now)
            while len(self._s) >= self.cap:          # the least recently used goes
                del self._s[min(self._s, key=lambda k: self._s[k].seen)]
            self._s[sid] = LoginSession(user.name, user_stamp(user), now)
        return sid

    def user(self, sid: Any, touch: bool = True) -> User | None:
        """The session's user, or None (and the session ended) if it has ended; `touch`: this use
        counts as activity (a page or an action; not the page's own data requests)."""
        if not isinstance(sid, str) or not sid:
            return None
        now = self.clock()
        with self._lock:
            s = self._s.get(sid)
            if s is None:
                return None
            if now - s.seen > self.idle_s:
                del self._s[sid]
                return None
        u = self.users.get(s.name)
        with self._lock:
            if u is None or not hmac.compare_digest(user_stamp(u).encode(), s.stamp.encode()):
                self._end_user(s.name)
                return None
            if sid in self._s and touch:
                s.seen = max(s.seen, now)
            return u if sid in self._s else None

    def name(self, sid: Any) -> str | None:
        with self._lock:
            s = self._s.get(sid) if isinstance(sid, str) else None
            return s.name if s else None

    def end_user(self, name: str) -> int:
        """End every session of `name`; how many there were."""
        with self._lock:
            return self._end_user(name)

    def _end_user(self, name: str) -> int:
        gone = [k for k, s in self._s.items() if s.name == name]
        for k in gone:
            del self._s[k]
        return len(gone)

    def _prune(self, now: float) -> None:
        for k in [k for k, s in self._s.items() if now - s.seen > self.idle_s]:
            del self._s[k]

    def __len__(self) -> int:
        return len(self._s)


# -- the session's signing key and the CSRF token ------------------------------------------


def load_secret(path: Path | str | None) -> str:
    """The session cookies' signing key: from `path` (made with a new random key, mode 0600, when
    absent), or a new random key for this run only (sessions end when the station restarts)."""
    if path is None:
        return secrets.token_hex(32)
    path = Path(path)
    if not path.exists():
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(secrets.token_hex(32) + "\n")
    files.check_file(path, "web secret", MAX_SECRET, UsersError)
    owner_only(path, "the web secret")
    text = files.read_text(path, "web secret", MAX_SECRET, UsersError).strip()
    if len(text) < 32 or not re.fullmatch(r"[0-9a-fA-F]+", text):
        raise UsersError(f"{path}: web secret: must be at least 32 hex digits (delete it: a new one is made)")
    return text


def csrf_token(session: MutableMapping[str, Any]) -> str:
    """The session's CSRF token (made on first use)."""
    tok = session.get("csrf")
    if not isinstance(tok, str) or len(tok) < 32:
        tok = session["csrf"] = secrets.token_urlsafe(32)
    return tok


def csrf_ok(session: MutableMapping[str, Any], given: str | None) -> bool:
    tok = session.get("csrf")
    return bool(isinstance(tok, str) and given and hmac.compare_digest(tok.encode(), given.encode()))
