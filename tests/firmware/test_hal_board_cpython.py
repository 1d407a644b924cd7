"""The board HAL's acquisition logic under CPython, with fake `machine` peripherals.

Checks what the ESP32 cannot show in a test run: the machine objects are
built from the board table (ropenode.boards) unless injected, the temperature
word is read only when a temperature input is fitted (else 0xFFFF,
docs/data-formats.md), the slow-input counter wraps instead of growing past
2**30, the bus-error counter saturates, and an armed recording takes the
records the node samples (and stops, without stopping the node, when the
flash fails), and Ctrl-C in the loop opens the maintenance window: the
watchdog re-armed with the board's maintenance timeout (clamped to what its
port's machine.WDT accepts), then the KeyboardInterrupt goes on to the REPL.
The ADS1115 driver and the front end in detail: test_ads1115_cpython.py.
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
        self.made = (a, k)
        self.ain = {}
        self.started = set()  # (address, ain) of every conversion started
        self.fail = False

    def writeto_mem(self, addr, reg, data):
        if self.fail:
            raise OSError(19)
        if reg == 1 and data[0] & 0x80:  # config, OS = 1: a conversion starts
            self.ain[addr] = (data[0] >> 4) & 3
            self.started.add((addr, self.ain[addr]))

    def readfrom_mem_into(self, addr, reg, buf):
        if self.fail:
            raise OSError(19)
        v = 0x8000 if reg == 1 else 1000 * ADDRS.index(addr) + 100 * self.ain.get(addr, 0)
        buf[0], buf[1] = v >> 8, v & 0xFF

    def scan(self):
        return [] if self.fail else list(ADDRS[:3])  # 0x4B does not answer


MADE = []  # (class name, args, kwargs) of every fake machine object built


def _fake(name):
    class Fake:
        IN = PULL_UP = PERIODIC = 0

        def __init__(self, *a, **k):
            self.a = a
            MADE.append((name, a, k))

        def value(self):
            return 1

        def write(self, data):  # the radio UART
            return len(data)

        def feed(self):  # the watchdog
            self.fed = getattr(self, "fed", 0) + 1

        def init(self, **k):  # the sample timer: never fires here
            self.inited = k

        def deinit(self):
            self.deinited = True

    Fake.__name__ = name
    return Fake


@pytest.fixture
def hal_board(monkeypatch):
    install_shim()
    MADE.clear()
    machine = types.ModuleType("machine")
    for name in ("UART", "WDT", "Counter", "Pin", "Timer"):
        setattr(machine, name, _fake(name))
    machine.I2C = FakeI2C
    machine.WDT_RESET = 3
    machine.reset_cause = lambda: 1  # power on
    monkeypatch.setitem(sys.modules, "machine", machine)
    monkeypatch.delitem(sys.modules, "ropenode.hal_board", raising=False)
    mod = importlib.import_module("ropenode.hal_board")
    clock = types.SimpleNamespace(sleep_us=lambda us: None, ticks_ms=lambda: 0, ticks_us=lambda: 0,
                                  ticks_diff=lambda a, b: a - b)
    from ropenode import ads1115, frontend
    for m in (mod, ads1115, frontend):
        monkeypatch.setattr(m, "time", clock)
    yield mod
    sys.modules.pop("ropenode.hal_board", None)
    sys.modules.pop("ropenode.bringup", None)


def _board(mod, ropes, fitted):
    return mod.Board(None, ropes, 200, fitted)


@pytest.mark.parametrize("name", ["esp32-devkitc", "esp32s3-devkitc"])
def test_buses_and_pins_come_from_the_board_table(hal_board, name):
    from ropenode import boards

    t = boards.get(name)
    b = hal_board.Board(None, 4, 200, False, t)
    pins = {m[1][0] for m in MADE if m[0] == "Pin"}
    assert pins == {t["i2c"][1], t["i2c"][2], t["rdy"], *t["encoder"][1:], *t["hall"], t["radio"][1], t["radio"][2]}
    (bus,), kw = b.i2c.made
    assert bus == t["i2c"][0] and kw["freq"] == t["i2c"][3] and kw["scl"].a[0] == t["i2c"][1]
    uart = [m for m in MADE if m[0] == "UART"]
    assert len(uart) == 1 and uart[0][1] == (t["radio"][0],)
    assert {k: uart[0][2][k] for k in ("baudrate", "bits", "parity", "stop")} == dict(
        baudrate=t["radio"][3], bits=8, parity=None, stop=1)
    assert [m[1][0] for m in MADE if m[0] == "Counter"] == [t["encoder"][0]]
    assert [f.address for f in b.fe.ads] == list(t["ads"])


def test_injected_buses_are_used_as_given(hal_board):
    from ropenode import boards

    i2c, uart = FakeI2C(), object()
    b = hal_board.Board(None, 2, 200, False, boards.get(), i2c=i2c, uart=uart)
    assert b.i2c is i2c and b.uart is uart and b.fe.ads[0].i2c is i2c
    assert not [m for m in MADE if m[0] == "UART"]


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
        assert 0 <= b.fe.k < 20
    assert aux == 50
    b.fe.k = 19
    b.rec[4] = 0
    b.acquire()
    assert b.fe.k == 0 and b.rec[4] == 0
    b.acquire()
    assert b.fe.k == 1 and b.rec[4] == 400


def test_bus_errors_read_as_failed_loops_and_the_count_saturates(hal_board):
    from ropenode import frontend

    b = _board(hal_board, 2, False)
    b.i2c.fail = True
    b.acquire()
    assert list(b.rec[:4]) == [0, 0, 0, 0] and b.fe.bus_errors > 0
    b.fe.bus_errors = frontend.COUNT_MAX - 1
    b.acquire()
    assert b.fe.bus_errors == frontend.COUNT_MAX


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


def test_bench_prints_each_loop_the_battery_and_the_timing(hal_board, capsys, monkeypatch):
    """bringup.bench (docs/hardware.md, bench steps 3-9) on the fake bus: chip i's codes are
    1000 i + 100 ain, so rope 2's pressure is code 1000 = word 2000 = 0.833 mA (LOW)."""
    sys.modules.pop("ropenode.bringup", None)
    from ropenode import bringup

    monkeypatch.setattr(bringup, "time", hal_board.time)
    bringup.bench(records=1)
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "I2C: found ['0x48', '0x49', '0x4a'] - table ['0x48', '0x49', '0x4a', '0x4b'] MISSING"
    assert out[1] == "pressure 1: word     0   0.000 mA  LOW (<3.6 mA)"
    assert out[2] == "pressure 2: word  2000   0.833 mA  LOW (<3.6 mA)"
    assert out[8] == "displacement 4: word  6200   2.583 mA  LOW (<3.6 mA)"
    assert out[9] == "battery: word 400  50 mV; temperature word 65535; encoder 1; hall 0"  # 200 codes x 125 uV x 2
    assert out[10].startswith("record: 0 us") and "bus errors 0, timeouts 0, rdy timeouts 0" in out[10]


# --- the watchdog and the maintenance window


def _interrupted_after(b, n):
    """Run b.run_forever with a timer tick before every pass; Ctrl-C (KeyboardInterrupt)
    lands in the n-th step. Returns the sampling watchdog (b.wdt while it sampled)."""
    step, seen = b.step, []

    def ticking_step():
        seen.append(b.wdt)
        if len(seen) == n:
            raise KeyboardInterrupt
        step()
        b.tick = True

    b.step = ticking_step
    b.tick = True
    with pytest.raises(KeyboardInterrupt):
        b.run_forever()
    assert len(set(map(id, seen))) == 1
    return seen[0]


def _wdts():
    return [m[2]["timeout"] for m in MADE if m[0] == "WDT"]


def test_the_loop_keeps_the_2s_watchdog_and_ctrl_c_opens_the_maintenance_window(hal_board, capsys):
    from ropenode import boards
    from ropenode.node import Node

    b = hal_board.Board(Node(None), 2, 200, False)
    sampling = _interrupted_after(b, 250)
    assert sampling.a == () and _wdts() == [boards.WDT_MS, 1_200_000]  # 20 min on the reference board
    assert sampling.fed >= 249 and not hasattr(b.wdt, "fed")  # nothing feeds the window's watchdog
    assert b.timer.deinited
    assert capsys.readouterr().out == ("ropenode: MAINTENANCE: sampling stopped; the watchdog resets "
                                       "the node in 1200 s unless it is reset before\n")
    assert hal_board.maintenance() is None and len(_wdts()) == 2  # once (main.py calls it again)


def test_maintenance_never_starts_a_watchdog(hal_board):
    """main.py calls it on any Ctrl-C: before the loop has started the watchdog, nothing."""
    assert hal_board.maintenance() is None and _wdts() == []


def test_the_window_is_clamped_to_what_the_port_accepts(hal_board):
    from ropenode import boards
    from ropenode.node import Node

    rp2 = dict(boards.get(), port="rp2", wdt_maintenance_ms=1_200_000)
    _interrupted_after(hal_board.Board(Node(None), 2, 200, False, rp2), 3)
    assert _wdts() == [2000, 8388]
    assert boards.maintenance_ms(dict(rp2, port="stm32")) == 32767
    assert boards.maintenance_ms(dict(rp2, port="zephyr")) == 2000  # unknown: no window, no crash
    assert boards.maintenance_ms(dict(rp2, wdt_maintenance_ms=10)) == 2000


def test_a_refused_timeout_still_reaches_the_repl(hal_board, capsys):
    """A port whose WDT refuses the timeout (ValueError, as rp2 above 8388 ms): the Ctrl-C still
    goes on (not the ValueError, which main.py would answer by restarting the loop)."""
    made = []

    class PickyWDT:
        def __init__(self, timeout):
            if timeout > 8388:
                raise ValueError("timeout exceeds 8388")
            made.append(timeout)

        def feed(self):
            pass

    from ropenode.node import Node

    hal_board.WDT = PickyWDT
    _interrupted_after(hal_board.Board(Node(None), 2, 200, False), 2)
    assert made == [2000]
    assert "the watchdog refused 1200000 ms: timeout exceeds 8388 - the node resets within 2 s" in capsys.readouterr().out


def test_every_board_table_has_a_window_its_port_accepts(hal_board):
    from ropenode import boards

    assert hal_board._WDT_MS == boards.WDT_MS
    for name, t in boards.BOARDS.items():
        boards.check(t)
        assert boards.maintenance_ms(t) == t["wdt_maintenance_ms"] >= 10 * 60_000, name
    ok = dict(boards.get())
    for port, ms in (("rp2", 8388), ("stm32", 32767), ("esp32", 3_600_000), ("esp32", 2000)):
        boards.check(dict(ok, port=port, wdt_maintenance_ms=ms))
    for port, ms, why in (("rp2", 8389, "rp2 needs 2000 .. 8388"), ("stm32", 40_000, "stm32 needs 2000 .. 32767"),
                          ("esp32", 1999, "esp32 needs"), ("esp32", 600.0 * 1000, "esp32 needs"),
                          ("esp32", None, "esp32 needs"), ("zephyr", 5000, "port 'zephyr': not one of")):
        with pytest.raises(ValueError, match=why):
            boards.check(dict(ok, port=port, wdt_maintenance_ms=ms))
