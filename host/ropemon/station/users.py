"""Who may do what: the users file, argon2 passwords, roles, and the login's cost bounded.

The users file (web.users and opcua.users in station.toml, written by `ropemon user add`) is
TOML, one table per user, readable by its owner only (mode 0600, refused otherwise, as a key
file is):

    [user.alice]
    role = "operator"                       # viewer, operator or engineer
    password = "$argon2id$v=19$m=65536,..."  # argon2id hash; the password itself is never stored

No user is shipped: a station without a users file (or with an empty one) lets nobody log in,
so nobody can act from the web or OPC UA. Roles, each with the rights of the ones before it:

    viewer      sees the pages (needed only where web.view_without_login is false)
    operator    acknowledges, shelves and unshelves alarms, accepts a rewound node
    engineer    takes an alarm out of service and returns it

Login costs are bounded (`HashPool`): every password check of the process (the web's logins and
OPC UA's) runs on one pool of HASH_WORKERS threads, with at most
HASH_QUEUE more waiting; a login beyond that is refused at once as busy (the web answers 429).
An unknown name is checked against a dummy hash on the same pool, so it costs what a known one
costs. Failed logins are counted per (address, name) and per address: LOGIN_FAILS of one name
from one address within LOGIN_WINDOW_S hold that name for that address only, ADDRESS_FAILS
from one address hold that address; nobody can lock an operator out from another address.
A caller that gives no address (OPC UA) is counted per name only.

The faces check their logins through `Users` (`login`, `check`, `start_login`, `get`,
`User.may`); the web's sessions are ropemon.station.web.auth. This module imports no web
library but argon2-cffi.
"""
from __future__ import annotations

import os
import re
import secrets
import stat
import threading
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from argon2 import PasswordHasher, extract_parameters
from argon2.exceptions import InvalidHashError, VerificationError

from ropemon.station import files
from ropemon.station.tomlfields import Table

ROLES = ("viewer", "operator", "engineer")
#: what each action needs
NEEDS = {"view": "viewer", "ack": "operator", "shelve": "operator", "unshelve": "operator",
         "accept_rewound": "operator", "remove": "engineer", "return": "engineer"}
USER_NAME = re.compile(r"^[a-z][a-z0-9_.-]{0,31}$")
MAX_USERS_TOML = 256 * files.KB
MIN_PASSWORD = 8
MAX_PASSWORD = 1024
LOGIN_FAILS, LOGIN_WINDOW_S = 5, 300.0   # this many failed logins of one name from one address: that pair waits
ADDRESS_FAILS = 20                       # this many failed logins from one address within the window: it waits
MAX_TRACKED = 10_000                     # addresses and (address, name) pairs with failures kept at most
HASH_WORKERS = 2                         # password checks at once in the process (each 64 MiB with the defaults)
HASH_QUEUE = 2                           # logins waiting for a worker; beyond: busy (the web answers 429)
HASH_WAIT_S = 2.0                        # a login that waited this long for a worker is refused busy instead
BUSY = "the station is busy checking other logins: try again in a moment"


class UsersError(ValueError):
    """A users file (or secret file) that cannot be used: the message names the field and the reason."""


@dataclass(frozen=True)
class User:
    name: str
    role: str
    password: str        # the argon2id hash

    def may(self, action: str) -> bool:
        return ROLES.index(self.role) >= ROLES.index(NEEDS[action])


def hasher() -> PasswordHasher:
    """argon2id with argon2-cffi's defaults (RFC 9106's low-memory profile)."""
    return PasswordHasher()


def check_name(name: str, what: str = "name") -> str:
    if not USER_NAME.match(name):
        raise UsersError(f"{what}: {name!r} must be 1-32 of a-z, 0-9, '_', '.' and '-', starting with a letter")
    return name


def check_password(password: str) -> str:
    if len(password) < MIN_PASSWORD:
        raise UsersError(f"password: at least {MIN_PASSWORD} characters")
    if len(password) > MAX_PASSWORD:
        raise UsersError(f"password: at most {MAX_PASSWORD} characters")
    if any(c in password for c in "\x00\r\n"):
        raise UsersError("password: no NUL or line breaks")
    return password


def owner_only(path: Path, what: str) -> None:
    mode = stat.S_IMODE(os.stat(path).st_mode)
    if os.name == "posix" and mode & 0o077:
        raise UsersError(f"{path}: {what} is readable or writable by others (mode {mode:04o}): it must be its "
                         f"owner's only: chmod 600 {path}")


def load_users(path: Path | str) -> dict[str, User]:
    """The users of a users file; UsersError names the file, the field and the reason."""
    path = Path(path)
    files.check_file(path, "users file", MAX_USERS_TOML, UsersError)
    owner_only(path, "the users file")
    doc = files.read_toml(path, "users file", MAX_USERS_TOML, UsersError)
    top = Table(doc, "", _named(path))
    out: dict[str, User] = {}
    if top.has("user"):
        users = top.table("user")
        for name in list(users.data):
            where = f"user.{name}"
            check_name(name, f"{path}: {where}")
            t = users.table(name)
            role = t.string("role", choices=ROLES)
            pw = t.string("password")
            if not pw.startswith("$argon2id$"):
                raise UsersError(f"{path}: {where}.password: not an argon2id hash (set it with ropemon user add)")
            try:
                extract_parameters(pw)
            except (InvalidHashError, ValueError):
                raise UsersError(f"{path}: {where}.password: not a valid argon2id hash (set it with "
                                 "ropemon user add)") from None
            t.finish()
            out[name] = User(name, role, pw)
        users.finish()
    top.finish()
    return out


def _named(path: Path) -> type[UsersError]:
    """An error class whose messages start with the file's name."""
    class InFile(UsersError):
        def __init__(self, msg: str) -> None:
            super().__init__(f"{path}: {msg}")
    return InFile


def _quote(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def save_users(path: Path | str, users: dict[str, User]) -> None:
    """Write the users file atomically, mode 0600 (owner only) from its first byte."""
    path = Path(path)
    lines = ["# ropemon web users: `ropemon user add FILE NAME --role ROLE`; passwords are argon2id hashes", ""]
    for name in sorted(users):
        u = users[name]
        lines += [f"[user.{check_name(u.name)}]", f"role = {_quote(u.role)}", f"password = {_quote(u.password)}", ""]
    files.write_private(path, "\n".join(lines).encode())


def add_user(path: Path | str, name: str, role: str, password: str, ph: PasswordHasher | None = None) -> User:
    """Add or replace `name` in the users file (made if absent); returns the user."""
    path = Path(path)
    check_name(name)
    if role not in ROLES:
        raise UsersError(f"role: must be one of {', '.join(ROLES)}, got {role!r}")
    check_password(password)
    users = load_users(path) if path.exists() else {}
    user = User(name, role, (ph or hasher()).hash(password))
    users[name] = user
    save_users(path, users)
    return user


def set_password(path: Path | str, name: str, password: str, ph: PasswordHasher | None = None) -> User:
    """A new password for a user already in the file (its role kept); a running station ends
    the user's sessions when it next reads the file."""
    check_password(password)
    users = load_users(path)
    if name not in users:
        raise UsersError(f"{path}: no user {name!r} (add one with ropemon user add)")
    user = users[name] = User(name, users[name].role, (ph or hasher()).hash(password))
    save_users(path, users)
    return user


def remove_user(path: Path | str, name: str) -> bool:
    users = load_users(path)
    if users.pop(name, None) is None:
        return False
    save_users(path, users)
    return True


@dataclass(frozen=True)
class LoginResult:
    """A login's outcome: the user, or why not; `busy`: refused because the hashing pool is full
    (not a failed login: try again; the web answers 429)."""

    user: User | None
    why: str | None = None
    busy: bool = False


class HashPool:
    """At most `workers` password checks at once, at most `queue` more waiting; `submit` returns
    None at once when the pool is full. `running` and `peak` count the checks running. The
    threads keep the station's CPU priority: a lowered one starves under load, and OPC UA's
    server waits for its logins on its own loop (asyncua checks a login synchronously)."""

    def __init__(self, workers: int = HASH_WORKERS, queue: int = HASH_QUEUE, wait_s: float = HASH_WAIT_S,
                 clock: Any = time.monotonic) -> None:
        self.workers, self.queue, self.wait_s, self.clock = workers, queue, wait_s, clock
        self._slots = threading.BoundedSemaphore(workers + queue)
        self._lock = threading.Lock()
        self._ex = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="ropemon-hash")
        self.running = self.peak = self.refused = self.late = 0

    def submit(self, fn: Any, *args: Any) -> Future | None:
        """fn(*args) on a worker (a Future), or None when `workers + queue` are taken; a call that
        waited more than wait_s for a worker returns LoginResult(None, BUSY, busy=True) instead."""
        if not self._slots.acquire(blocking=False):
            with self._lock:
                self.refused += 1
            return None
        queued = self.clock()

        def job() -> Any:
            try:
                if self.clock() - queued > self.wait_s:
                    with self._lock:
                        self.late += 1
                    return LoginResult(None, BUSY, busy=True)
                with self._lock:
                    self.running += 1
                    self.peak = max(self.peak, self.running)
                try:
                    return fn(*args)
                finally:
                    with self._lock:
                        self.running -= 1
            finally:
                self._slots.release()

        try:
            return self._ex.submit(job)
        except RuntimeError:   # pragma: no cover  (interpreter shutting down)
            self._slots.release()
            return None


_POOL: HashPool | None = None
_POOL_LOCK = threading.Lock()


def shared_pool() -> HashPool:
    """The process's one hashing pool (the web face's and OPC UA's `Users` share it)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = HashPool()
        return _POOL


class _Fails:
    """Failure times per key within a window, for at most `cap` keys (the stalest dropped first)."""

    def __init__(self, limit: int, window_s: float, cap: int = MAX_TRACKED) -> None:
        self.limit, self.window_s, self.cap = limit, window_s, cap
        self._t: dict[Any, deque[float]] = {}

    def held_for(self, key: Any, now: float) -> float:
        """Seconds this key is still held (0: not held)."""
        q = self._t.get(key)
        if q is None:
            return 0.0
        while q and now - q[0] >= self.window_s:
            q.popleft()
        if not q:
            del self._t[key]
            return 0.0
        return self.window_s - (now - q[0]) if len(q) >= self.limit else 0.0

    def add(self, key: Any, now: float) -> None:
        q = self._t.get(key)
        if q is None:
            if len(self._t) >= self.cap:
                self._prune(now)
            q = self._t[key] = deque(maxlen=self.limit)
        q.append(now)

    def clear(self, key: Any) -> None:
        self._t.pop(key, None)

    def _prune(self, now: float) -> None:
        for k in [k for k, q in self._t.items() if not q or now - q[-1] >= self.window_s]:
            del self._t[k]
        if len(self._t) >= self.cap:     # still full: drop the half failed least recently
            for k in sorted(self._t, key=lambda k: self._t[k][-1])[: len(self._t) // 2]:
                del self._t[k]

    def __len__(self) -> int:
        return len(self._t)


class Users:
    """The users file as the web face reads it: read again when it changes; logins checked
    with argon2 on the process's hashing pool (an unknown name costs as much as a wrong
    password), throttled per (address, name) and per address."""

    def __init__(self, path: Path | str | None, ph: PasswordHasher | None = None,
                 clock: Any = time.monotonic, pool: HashPool | None = None) -> None:
        self.path = Path(path) if path is not None else None
        self.ph = ph or hasher()
        self.clock = clock
        self.pool = pool or shared_pool()
        self._lock = threading.Lock()
        self._users: dict[str, User] = {}
        self._stamp: tuple[int, int, int] | None = None
        self._fails = _Fails(LOGIN_FAILS, LOGIN_WINDOW_S)          # (address, name)
        self._address_fails = _Fails(ADDRESS_FAILS, LOGIN_WINDOW_S)  # address
        self._dummy = self.ph.hash(secrets.token_hex(16))
        self.error: str | None = None
        if self.path is not None:
            self._users = load_users(self.path)      # refused at start: serve does not start
            self._stamp = self._file_stamp()

    def _file_stamp(self) -> tuple[int, int, int] | None:
        try:
            st = os.stat(self.path)  # type: ignore[arg-type]
        except OSError:
            return None
        return (st.st_mtime_ns, st.st_size, st.st_ino)   # the inode: a file replaced in the same tick

    def _refresh(self) -> None:
        if self.path is None:
            return
        stamp = self._file_stamp()
        if stamp == self._stamp:
            return
        try:
            self._users = load_users(self.path)
            self.error = None
        except (UsersError, OSError) as e:     # keep the users read before; say why
            self.error = str(e)
        self._stamp = stamp

    def all(self) -> dict[str, User]:
        with self._lock:
            self._refresh()
            return dict(self._users)

    def get(self, name: str | None) -> User | None:
        if not name:
            return None
        return self.all().get(name)

    def login(self, name: str, password: str, client: str | None = None) -> tuple[User | None, str | None]:
        """(user, None), or (None, why) for a refused login (also a busy pool); blocks until checked."""
        r = self.check(name, password, client)
        return r.user, r.why

    def check(self, name: str, password: str, client: str | None = None) -> LoginResult:
        """The login's outcome, waiting for the hashing pool (`start_login` without waiting)."""
        return self.start_login(name, password, client).result()

    def start_login(self, name: str, password: str, client: str | None = None) -> Future:
        """A Future of the login's LoginResult: done at once when the name is held for this
        client address (or the address is), or the pool is full; else when argon2 has checked."""
        now = self.clock()
        addr = client or ""                 # "": a caller without addresses (OPC UA): per name only
        with self._lock:
            self._refresh()
            held_addr = self._address_fails.held_for(addr, now) if addr else 0.0
            held_name = self._fails.held_for((addr, name), now)
            user = self._users.get(name)
        if held_addr:
            return _done(LoginResult(None, f"too many failed logins from this address: try again in {held_addr:.0f} s"))
        if held_name:
            return _done(LoginResult(None, f"too many failed logins for this name: try again in {held_name:.0f} s"))
        fut = self.pool.submit(self._verify, user, name, password, addr)
        return fut if fut is not None else _done(LoginResult(None, BUSY, busy=True))

    def _verify(self, user: User | None, name: str, password: str, addr: str) -> LoginResult:
        ok = False
        try:
            ok = self.ph.verify(user.password if user else self._dummy, password) and user is not None
        except (VerificationError, InvalidHashError):
            ok = False
        now = self.clock()
        with self._lock:
            if not ok:
                self._fails.add((addr, name), now)
                if addr:
                    self._address_fails.add(addr, now)
                return LoginResult(None, "wrong name or password")
            self._fails.clear((addr, name))
        return LoginResult(user)


def _done(result: LoginResult) -> Future:
    f: Future = Future()
    f.set_result(result)
    return f
