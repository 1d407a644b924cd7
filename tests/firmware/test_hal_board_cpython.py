"""The board HAL's acquisition logic under CPython, with fake `machine` peripherals.

Checks what the ESP32 cannot show in a test run: the temperature word is read
only when a temperature input is fitted (else 0xFFFF, docs/data-formats.md),
the slow-input counter wraps instead of growing past 2**30, the bus-error
counter saturates, and an armed recording takes the records the node samples
(and stops, without stopping the node, when the flash fails).
"""
from __future__ import annotations

import importlib
import sys
import types

import pytest

from ropemon.firmware import install_shim

ADDRS = (0x48, 0x49, 0x4A, 0x4B)


class FakeI2C:
    """ADS1115s that convert the input last started: code = 1000 * chip + 100 * ain."""

    def __init__(self, *a, **k):
        self.ain = {}
        self.started = set()  # (address, ain) of every conversion started
        self.fail = False

    def writeto_mem(self, addr, reg, data):
        if self.fail:
            raise OSError(19)
        self.ain[addr] = ((data[0] << 8) >> 12) & 3
        self.started.add((addr, self.ain[addr]))

    def readfrom_mem_into(self, addr, reg, buf):
        if self.fail:
            raise OSError(19)
        v = 1000 * ADDRS.index(addr) + 100 * self.ain.get(addr, 0)
        buf[0], buf[1] = v >> 8, v & 0xFF


class _Any:
    IN = PULL_UP = PERIODIC = 0

    def __init__(self, *a, **k):
        pass

    def value(self):
        return 1

    def write(self, data):  # the radio UART
        return len(data)


@pytest.fixture
def hal_board(monkeypatch):
    install_shim()
    machine = types.ModuleType("machine")
    for name in ("UART", "WDT", "Counter", "Pin", "Timer"):
        setattr(machine, name, _Any)
    machine.I2C = FakeI2C
    monkeypatch.setitem(sys.modules, "machine", machine)
    monkeypatch.delitem(sys.modules, "ropenode.hal_board", raising=False)
    mod = importlib.import_module("ropenode.hal_board")
    monkeypatch.setattr(mod, "time", types.SimpleNamespace(sleep_us=lambda us: None, ticks_ms=lambda: 0,
                                                           ticks_diff=lambda a, b: a - b))
    yield mod
    sys.modules.pop("ropenode.hal_board", None)


def _board(mod, ropes, fitted):
    return mod.Board(None, ropes, 200, fitted)


@pytest.mark.parametrize("ropes", [1, 4])
def test_temperature_word_is_0xffff_unless_an_input_is_fitted(hal_board, ropes):
    b = _board(hal_board, ropes, False)
    b.acquire()
    assert b.rec[2 * ropes] == 2 * 200              # battery: chip 0 AIN2
    assert b.rec[2 * ropes + 1] == 0xFFFF
    assert (0x49, 2) not in b.i2c.started and (0x48, 2) in b.i2c.started
    b = _board(hal_board, ropes, True)
    b.acquire()
    assert b.rec[2 * ropes + 1] == 2 * (1000 + 200)  # chip 1 AIN2
    assert list(b.rec[:2 * ropes]) == [2 * 1000 * i for i in range(ropes)] + [2 * (1000 * i + 100)
                                                                             for i in range(ropes)]


def test_aux_counter_wraps_and_slow_inputs_are_read_one_sample_in_20(hal_board):
    b = _board(hal_board, 2, True)
    aux = 0
    for _ in range(1000):
        b.rec[4] = 0
        b.acquire()
        aux += b.rec[4] != 0
        assert 0 <= b.k < 20
    assert aux == 50
    b.k = 19
    b.rec[4] = 0
    b.acquire()
    assert b.k == 0 and b.rec[4] == 0
    b.acquire()
    assert b.k == 1 and b.rec[4] == 400


def test_bus_errors_read_as_failed_loops_and_the_count_saturates(hal_board):
    b = _board(hal_board, 2, False)
    b.i2c.fail = True
    b.acquire()
    assert list(b.rec[:4]) == [0, 0, 0, 0] and b.i2c_errors > 0
    b.i2c_errors = hal_board._COUNT_MAX - 1
    b.acquire()
    assert b.i2c_errors == hal_board._COUNT_MAX


def test_an_armed_recording_takes_the_records_the_node_samples(hal_board, tmp_path):
    from ropenode import rsens
    from ropenode.node import Node

    root = str(tmp_path) + "/"
    assert hal_board._recorder(2, 200, root) is None  # not armed
    (tmp_path / rsens.RECORD_FLAG).write_text("1\n")
    b = hal_board.Board(Node(None), 2, 200, True)
    b.recorder = hal_board._recorder(2, 200, root)
    assert not (tmp_path / rsens.RECORD_FLAG).exists()  # a reset does not record again
    want = []
    for _ in range(250):
        b.step()
        want.append(list(b.rec))
    assert b.recorder is None  # one second: done, the file closed
    data = (tmp_path / rsens.RECORD_FILE).read_bytes()
    assert data[:12] == b"RSNS" + bytes([1, 0, 2, 0, 200, 0, 0, 0])
    words = [int.from_bytes(data[o:o + 2], "little") for o in range(12, len(data), 2)]
    assert [words[k:k + 8] for k in range(0, len(words), 8)] == want[:200]


def test_a_failing_flash_stops_the_recording_not_the_node(hal_board):
    from ropenode import rsens
    from ropenode.node import Node

    class FullFlash:
        def __init__(self):
            self.closed = False

        def write(self, data):
            if len(data) > 12:
                raise OSError(28)  # ENOSPC
            return len(data)

        def close(self):
            self.closed = True

    flash = FullFlash()
    node = Node(None)
    b = hal_board.Board(node, 2, 200, False)
    b.recorder = rsens.Writer(flash, 2, 200, 1000)
    for _ in range(200):
        b.step()
    assert b.recorder is None and flash.closed
    assert node.frame_seq.count == 10  # the node went on framing: 200 samples, 10 windows
