"""The station's log summarises repeated messages (`ropemon.station.logsummary`): the first of
a kind is written, then at most one line per kind per interval counts the rest."""
from __future__ import annotations

import io
import logging
import time

import pytest

from ropemon.station import logsummary
from ropemon.station.logsummary import PEER, Summarised


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def summarised():
    out, clock = io.StringIO(), Clock()
    target = logging.StreamHandler(out)
    target.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    h = Summarised(target, interval_s=60.0, clock=clock, timers=False)
    logger = logging.getLogger("test_logsummary.pymodbus")
    logger.propagate, logger.level = False, logging.DEBUG
    logger.addHandler(h)
    yield logger, h, clock, out
    logger.removeHandler(h)
    h.close()


def lines(out: io.StringIO) -> list[str]:
    return out.getvalue().splitlines()


def test_ten_thousand_errors_from_one_peer_are_one_line_then_one_summary_per_interval(summarised):
    log, h, clock, out = summarised
    token = PEER.set("10.0.0.5")
    try:
        for i in range(10_000):            # pymodbus formats its messages itself: the numbers vary
            log.error(f"Invalid Modbus protocol id: {i % 700 + 1}")
            clock.t += 0.005                # 50 s of them
        assert lines(out) == ["ERROR test_logsummary.pymodbus: Invalid Modbus protocol id: 1 (from 10.0.0.5)"]
        clock.t = 1060.0
        h.flush()
        assert lines(out)[1:] == ['ERROR test_logsummary.pymodbus: 9,999 more like "Invalid Modbus protocol id: #" '
                                  'from 10.0.0.5 in the last 60 s']
        for _ in range(100):                # still coming: still one line per interval
            log.error("Invalid Modbus protocol id: 3")
            clock.t += 0.5
        h.flush()
        assert len(lines(out)) == 2
        clock.t = 1120.0
        h.flush()
        assert lines(out)[2:] == ['ERROR test_logsummary.pymodbus: 100 more like "Invalid Modbus protocol id: #" '
                                  'from 10.0.0.5 in the last 60 s']
        clock.t = 1180.0                    # a quiet interval: the kind is forgotten
        h.flush()
        assert len(lines(out)) == 3
        log.error("Invalid Modbus protocol id: 9")
        assert lines(out)[3:] == ["ERROR test_logsummary.pymodbus: Invalid Modbus protocol id: 9 (from 10.0.0.5)"]
    finally:
        PEER.reset(token)


def test_another_peer_message_or_logger_is_another_kind(summarised):
    log, h, clock, out = summarised
    for peer in ("10.0.0.5", "10.0.0.6", "10.0.0.5"):
        token = PEER.set(peer)
        log.warning("Unable to decode frame %s", 1)
        log.warning("Unable to decode frame %s", 2)
        PEER.reset(token)
    log.warning("login refused: %r from %s: %s", "olga", "10.0.0.7", "bad password")   # the peer in an argument
    log.warning("login refused: %r from %s: %s", "olga", "10.0.0.7", "bad password")
    log.warning("Refusing connection from %s: at max_connections=%s", ("10.0.0.8", 50123), 3)  # a (host, port)
    log.warning("Refusing connection from %s: at max_connections=%s", ("10.0.0.8", 50124), 3)
    other = logging.getLogger("test_logsummary.pymodbus.other")
    other.warning("Unable to decode frame %s", 3)
    assert lines(out) == [
        "WARNING test_logsummary.pymodbus: Unable to decode frame 1 (from 10.0.0.5)",
        "WARNING test_logsummary.pymodbus: Unable to decode frame 1 (from 10.0.0.6)",
        "WARNING test_logsummary.pymodbus: login refused: 'olga' from 10.0.0.7: bad password",
        "WARNING test_logsummary.pymodbus: Refusing connection from ('10.0.0.8', 50123): at max_connections=3",
        "WARNING test_logsummary.pymodbus.other: Unable to decode frame 3"]
    h.close()                               # at close: what was held back, counted
    assert sorted(lines(out)[5:]) == sorted([
        'WARNING test_logsummary.pymodbus: 3 more like "Unable to decode frame %s" from 10.0.0.5 in the last 0.0 s',
        'WARNING test_logsummary.pymodbus: 1 more like "Unable to decode frame %s" from 10.0.0.6 in the last 0.0 s',
        'WARNING test_logsummary.pymodbus: 1 more like "login refused: %r from %s: %s" from 10.0.0.7 in the last 0.0 s',
        'WARNING test_logsummary.pymodbus: 1 more like "Refusing connection from %s: at max_connections=%s" '
        'from 10.0.0.8 in the last 0.0 s'])


def test_a_long_message_is_cut(summarised):
    log, h, clock, out = summarised
    log.error("Invalid Modbus protocol id: 1" + "".join(f"\n>>>>> recv: 0x0 0x{i:x}" for i in range(20)))
    assert lines(out) == ["ERROR test_logsummary.pymodbus: Invalid Modbus protocol id: 1",
                          ">>>>> recv: 0x0 0x0", ">>>>> recv: 0x0 0x1", "[18 more lines not shown]"]


def test_the_summary_comes_when_its_interval_ends_without_another_record():
    out = io.StringIO()
    h = Summarised(logging.StreamHandler(out), interval_s=0.2)
    log = logging.getLogger("test_logsummary.timed")
    log.propagate = False
    log.addHandler(h)
    try:
        for i in range(50):
            log.warning("Got malformed header %s", i)
        assert len(lines(out)) == 1
        deadline = time.monotonic() + 5
        while len(lines(out)) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert lines(out)[1].startswith('49 more like "Got malformed header %s" in the last 0.')
    finally:
        log.removeHandler(h)
        h.close()


def test_serves_logging_takes_asyncua_and_pymodbus_through_the_summary(monkeypatch):
    """`install` (what `ropemon serve` calls): asyncua's and pymodbus's loggers at WARNING and
    summarised, the station's own at INFO."""
    asyncua = pytest.importorskip("asyncua.server.binary_server_asyncio")
    pytest.importorskip("pymodbus")
    from pymodbus.logging import Log

    # pymodbus keeps, per process, the last frames (appended to its next error) and its last
    # message (not repeated): what a Modbus test before this one in the same process left
    monkeypatch.setattr(Log, "frame_dump", [])
    monkeypatch.setattr(Log, "last_log_text", "")

    out = io.StringIO()
    h = logsummary.install(out, "ropemon serve")
    try:
        assert logsummary.install(out, "ropemon serve") is h          # once
        ua = asyncua._logger                                           # asyncua's own logger
        for i in range(1000):
            ua.info("New connection from %s", ("10.0.0.9", 40000 + i))   # below WARNING: not written
            ua.error("Got malformed header %s", f"Header(type=b'XYZ', size={i})")
            ua.warning("Refusing connection from %s: at max_connections=%s", ("10.0.0.9", 40000 + i), 50)
        for i in range(1000):
            Log.debug("Processing: {}", bytes([i & 0xFF]), ":hex")     # pymodbus: debug not written
            Log.error("Invalid Modbus protocol id: {}", i + 1)
        audit = logging.getLogger("ropemon.web.audit")       # below WARNING: every one written
        audit.info("login: %s (%s) from %s", "olga", "operator", "10.20.0.7")
        audit.info("login: %s (%s) from %s", "piet", "viewer", "10.20.0.7")
        assert lines(out) == [
            "ropemon serve: ERROR asyncua.server.binary_server_asyncio: Got malformed header Header(type=b'XYZ', size=0)",
            "ropemon serve: WARNING asyncua.server.binary_server_asyncio: Refusing connection from ('10.0.0.9', 40000): "
            "at max_connections=50",
            "ropemon serve: ERROR pymodbus.logging: Invalid Modbus protocol id: 1",
            "ropemon serve: INFO ropemon.web.audit: login: olga (operator) from 10.20.0.7",
            "ropemon serve: INFO ropemon.web.audit: login: piet (viewer) from 10.20.0.7"]
    finally:
        logsummary.uninstall(h)
    assert len(lines(out)) == 8                  # the three summaries, at close
    assert h not in logging.getLogger("ropemon").handlers and logging.getLogger("asyncua").level == logging.NOTSET
