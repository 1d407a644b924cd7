"""Who may do what on the web face: the users file, argon2 passwords, roles, sessions, CSRF.

The users file (web.users in station.toml, written by `ropemon user add`) is TOML, one table
per user, readable by its owner only (mode 0600, refused otherwise, as a key file is):

    [user.alice]
    role = "operator"                       # viewer, operator or engineer
    password = "$argon2id$v=19$m=65536,..."  # argon2id hash; the password itself is never stored

No user is shipped: a station without a users file (or with an empty one) lets nobody log in,
so nobody can act from the web. Roles, each with the rights of the ones before it:

    viewer      sees the pages (needed only where web.view_without_login is false)
    operator    acknowledges, shelves and unshelves alarms, accepts a rewound node
    engineer    takes an alarm out of service and returns it

The session cookie (Starlette's SessionMiddleware, signed with itsdangerous) carries the user's
name and a CSRF token; the user's role is looked up in the users file at each request, so a
user removed from the file loses its rights at once (the file is read again when it changes).
Every action (POST) carries the token (form field `csrf` or header X-CSRF-Token), or is refused.

Other faces (OPC UA) check their logins against the same file through `Users` (`login`, `get`,
`User.may`): this module imports no web library but argon2-cffi.
"""
from __future__ import annotations

import hmac
import os
import re
import secrets
import stat
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, MutableMapping

from argon2 import PasswordHasher, extract_parameters
from argon2.exceptions import InvalidHashError, VerificationError

from ropemon.commission.tomlfields import Table
from ropemon.station import files

ROLES = ("viewer", "operator", "engineer")
#: what each action needs
NEEDS = {"view": "viewer", "ack": "operator", "shelve": "operator", "unshelve": "operator",
         "accept_rewound": "operator", "remove": "engineer", "return": "engineer"}
USER_NAME = re.compile(r"^[a-z][a-z0-9_.-]{0,31}$")
MAX_USERS_TOML = 256 * files.KB
MAX_SECRET = 4 * files.KB
MIN_PASSWORD = 8
MAX_PASSWORD = 1024
LOGIN_FAILS, LOGIN_WINDOW_S = 5, 300.0   # this many failed logins of one name within the window: wait


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


def _owner_only(path: Path, what: str) -> None:
    mode = stat.S_IMODE(os.stat(path).st_mode)
    if os.name == "posix" and mode & 0o077:
        raise UsersError(f"{path}: {what} is readable or writable by others (mode {mode:04o}): it must be its "
                         f"owner's only: chmod 600 {path}")


def load_users(path: Path | str) -> dict[str, User]:
    """The users of a users file; UsersError names the file, the field and the reason."""
    path = Path(path)
    files.check_file(path, "users file", MAX_USERS_TOML, UsersError)
    _owner_only(path, "the users file")
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


def remove_user(path: Path | str, name: str) -> bool:
    users = load_users(path)
    if users.pop(name, None) is None:
        return False
    save_users(path, users)
    return True


class Users:
    """The users file as the web face reads it: read again when it changes; logins checked
    with argon2 (an unknown name costs as much as a wrong password), throttled per name."""

    def __init__(self, path: Path | str | None, ph: PasswordHasher | None = None,
                 clock: Any = time.monotonic) -> None:
        self.path = Path(path) if path is not None else None
        self.ph = ph or hasher()
        self.clock = clock
        self._lock = threading.Lock()
        self._users: dict[str, User] = {}
        self._stamp: tuple[int, int] | None = None
        self._fails: dict[str, list[float]] = {}
        self._dummy = self.ph.hash(secrets.token_hex(16))
        self.error: str | None = None
        if self.path is not None:
            self._users = load_users(self.path)      # refused at start: serve does not start
            self._stamp = self._file_stamp()

    def _file_stamp(self) -> tuple[int, int] | None:
        try:
            st = os.stat(self.path)  # type: ignore[arg-type]
        except OSError:
            return None
        return (st.st_mtime_ns, st.st_size)

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

    def login(self, name: str, password: str) -> tuple[User | None, str | None]:
        """(user, None), or (None, why) for a refused login."""
        now = self.clock()
        with self._lock:
            self._refresh()
            fails = [t for t in self._fails.get(name, []) if now - t < LOGIN_WINDOW_S]
            self._fails[name] = fails
            user = self._users.get(name)
        if len(fails) >= LOGIN_FAILS:
            wait = LOGIN_WINDOW_S - (now - fails[0])
            return None, f"too many failed logins for this name: try again in {wait:.0f} s"
        ok = False
        try:
            ok = self.ph.verify(user.password if user else self._dummy, password) and user is not None
        except (VerificationError, InvalidHashError):
            ok = False
        if not ok:
            with self._lock:
                self._fails.setdefault(name, []).append(now)
            return None, "wrong name or password"
        with self._lock:
            self._fails.pop(name, None)
        return user, None


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
    _owner_only(path, "the web secret")
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
