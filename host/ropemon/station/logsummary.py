"""Log lines that a flood of bad traffic cannot multiply: repeated messages summarised.

`Summarised` wraps the handler that writes the station's log (stderr, the journal under
systemd). The first record of a kind goes through; more of the same kind within
`interval_s` are counted, not written, and each interval that had some ends in one line:

    ropemon serve: ERROR pymodbus.logging: 9,999 more like "Invalid Modbus protocol id: #"
    from 10.0.0.5 in the last 60 s

A kind is the logger's name, the message template (`record.msg`, its digits blanked:
pymodbus formats its messages itself, so each frame's numbers would be a new kind) and
the peer the record is about, where one is found: `record.peer`, the `PEER` context
variable (the Modbus face sets it while it handles a connection's bytes), a (host, port)
argument, or an IPv4 address in the message. A kind that has been quiet for a whole
interval starts again with its first record written. Records below WARNING (the station's
own INFO: logins, logouts) are all written. A record's message is cut to `max_lines` lines
(pymodbus appends its last 20 frames to each error). `install` puts one such handler on
the `ropemon`, `pymodbus` and `asyncua` loggers (`ropemon serve`).
"""
from __future__ import annotations

import contextvars
import logging
import re
import threading
import time
from typing import IO, Callable

#: the peer whose traffic is being handled on this thread or task ("": none)
PEER: contextvars.ContextVar[str] = contextvars.ContextVar("log_peer", default="")

#: logger -> level `install` sets: the station's own messages, the libraries' warnings and errors
LEVELS = {"ropemon": logging.INFO, "pymodbus": logging.WARNING, "asyncua": logging.WARNING}

_DIGITS = re.compile(r"0x[0-9a-fA-F]+|\d+")
_IPV4 = re.compile(r"(?<![\d.])(\d{1,3}(?:\.\d{1,3}){3})(?![\d.])")


def peer_of(record: logging.LogRecord, first_line: str) -> str:
    """The peer a record is about ("": none found)."""
    peer = getattr(record, "peer", None) or PEER.get()
    if peer:
        return str(peer)
    args = record.args if isinstance(record.args, tuple) else ()
    for a in args:
        if isinstance(a, tuple) and len(a) >= 2 and isinstance(a[0], str) and isinstance(a[1], int):
            return a[0]
    m = _IPV4.search(first_line)
    return m.group(1) if m else ""


def _seconds(s: float) -> str:
    return f"{s:.0f}" if s >= 10 else f"{s:.1f}"


class _Kind:
    __slots__ = ("start", "count", "last")

    def __init__(self, start: float) -> None:
        self.start, self.count = start, 0
        self.last: logging.LogRecord | None = None      # the newest record held back


class Summarised(logging.Handler):
    """Forwards to `target` the first record of each kind, then at most one summary line per
    kind per `interval_s` (module docstring); records below `min_level` all go through.
    `timers=False`: summaries only when records come, at `flush()` and at `close()` (for a
    test's own clock)."""

    def __init__(self, target: logging.Handler, interval_s: float = 60.0, max_lines: int = 4,
                 max_kinds: int = 1000, min_level: int = logging.WARNING,
                 clock: Callable[[], float] = time.monotonic, timers: bool = True) -> None:
        super().__init__()
        self.target, self.interval_s, self.max_lines, self.max_kinds = target, interval_s, max_lines, max_kinds
        self.min_level = min_level
        self.clock, self.timers = clock, timers
        self._kinds: dict[tuple[str, str, str], _Kind] = {}
        self._timer: threading.Timer | None = None
        self._next_due = float("inf")               # the earliest end of a kind's interval
        self.levels_before: dict[str, int] = {}     # `install`'s loggers' levels before it

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self._emit(record)
        except Exception:  # noqa: BLE001 - logging's convention: report, do not raise
            self.handleError(record)

    def _emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        first = text.split("\n", 1)[0]
        if record.levelno < self.min_level:
            self._write(record, text, "")
            return
        peer = peer_of(record, first)
        template = _DIGITS.sub("#", str(record.msg).split("\n", 1)[0])[:120]
        kind = (record.name, template, peer)
        now = self.clock()
        if now >= self._next_due:
            self._due(now)
        k = self._kinds.get(kind)
        if k is None and len(self._kinds) >= self.max_kinds:
            kind = (record.name, "(other messages)", "")      # too many kinds at once: the rest as one
            k = self._kinds.get(kind)
        if k is not None:
            k.count += 1
            k.last = record
            self._arm(k.start + self.interval_s - now)
            return
        self._kinds[kind] = _Kind(now)
        self._next_due = min(self._next_due, now + self.interval_s)
        self._write(record, text, peer)

    def _write(self, record: logging.LogRecord, text: str, peer: str) -> None:
        """The record, its peer named, cut to `max_lines`."""
        lines = text.split("\n")
        if peer and peer not in lines[0]:
            lines[0] += f" (from {peer})"
        if len(lines) > self.max_lines:
            lines = lines[:self.max_lines - 1] + [f"[{len(lines) - self.max_lines + 1} more lines not shown]"]
        record.msg, record.args = "\n".join(lines), None
        self.target.handle(record)

    def _due(self, now: float, all_: bool = False) -> None:
        """The summaries of the kinds whose interval is over (all_: of every kind); forget the
        kinds that had nothing more."""
        for kind, k in list(self._kinds.items()):
            if not all_ and now - k.start < self.interval_s:
                continue
            if k.count and k.last is not None:
                name, template, peer = kind
                where = f" from {peer}" if peer else ""
                s = logging.LogRecord(k.last.name, k.last.levelno, k.last.pathname, k.last.lineno,
                                      '%s more like "%s"%s in the last %s s',
                                      (f"{k.count:,}", template, where, _seconds(now - k.start)), None)
                self.target.handle(s)
                k.start, k.count, k.last = now, 0, None
            else:
                del self._kinds[kind]
        self._next_due = min((k.start + self.interval_s for k in self._kinds.values()), default=float("inf"))

    def _arm(self, after_s: float) -> None:
        if not self.timers or self._timer is not None:
            return
        self._timer = threading.Timer(max(0.01, after_s), self._fire)
        self._timer.daemon = True
        self._timer.start()

    def _fire(self) -> None:
        with self.lock:  # type: ignore[union-attr]
            self._timer = None
            now = self.clock()
            self._due(now)
            pending = [k.start + self.interval_s - now for k in self._kinds.values() if k.count]
            if pending:
                self._arm(min(pending))

    def flush(self) -> None:
        with self.lock:  # type: ignore[union-attr]
            self._due(self.clock())
        self.target.flush()

    def close(self) -> None:
        with self.lock:  # type: ignore[union-attr]
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None
            self._due(self.clock(), all_=True)
        self.target.flush()
        super().close()


def install(stream: IO[str], prefix: str, interval_s: float = 60.0) -> Summarised:
    """Write the `LEVELS` loggers' records to `stream` as "PREFIX: LEVEL LOGGER: MESSAGE",
    summarised; once (a second call returns the handler of the first)."""
    for h in logging.getLogger("ropemon").handlers:
        if isinstance(h, Summarised):
            return h
    target = logging.StreamHandler(stream)
    target.setFormatter(logging.Formatter(f"{prefix}: %(levelname)s %(name)s: %(message)s"))
    handler = Summarised(target, interval_s)
    handler.levels_before = {name: logging.getLogger(name).level for name in LEVELS}
    for name, level in LEVELS.items():
        logger = logging.getLogger(name)
        logger.addHandler(handler)
        logger.setLevel(level)
    return handler


def uninstall(handler: Summarised) -> None:
    """Take `install`'s handler off again, its last summaries written, the levels as before (tests)."""
    for name, level in handler.levels_before.items():
        logging.getLogger(name).removeHandler(handler)
        logging.getLogger(name).setLevel(level)
    handler.close()


__all__ = ["LEVELS", "PEER", "Summarised", "install", "uninstall", "peer_of"]
