"""The ADS1115 driver and the board front end allocate nothing per sample: under heap_lock.

Runs under the real `micropython` (tests/run_micropython.py), where any heap
allocation inside heap_lock() raises MemoryError, with the real time module
(sleep_us, ticks_us); and under CPython (pytest), where heap_lock is the shim's
no-op and a fake clock stands in for the MicroPython time functions. The bus
is a fake I2C of four ADS1115s (registers as in the datasheet); a healthy
record, a record with a chip whose conversion never finishes, and the
conversion-ready line are each run inside the lock. A bus error (an OSError
from the bus) is checked outside it: raising allocates the exception, as
machine.I2C's does on the board. The register-level and NAMUR details are in
test_ads1115_cpython.py.
"""
import sys

import micropython

from ropenode import ads1115, boards, frontend
from ropenode.ads1115 import ADS1115, single

ON_MICROPYTHON = sys.implementation.name == "micropython"
ADDRS = (0x48, 0x49, 0x4A, 0x4B)
REF = boards.get("esp32-devkitc")
LOCKED = 200  # records acquired inside one heap_lock: ten slow rounds


class _Clock:
    """CPython only: time.ticks_us / ticks_diff / sleep_us."""

    def __init__(self):
        self.us = 0

    def ticks_us(self):
        self.us += 20
        return self.us

    def ticks_diff(self, a, b):
        return a - b

    def sleep_us(self, us):
        self.us += us


def _with_clock(fn):
    """Run fn(); under CPython with the fake clock in the driver and the front end."""
    if ON_MICROPYTHON:
        return fn()
    saved = ads1115.time, frontend.time
    ads1115.time = frontend.time = _Clock()
    try:
        return fn()
    finally:
        ads1115.time, frontend.time = saved


class FakeBus:
    """Four ADS1115s: a config write with OS = 1 converts input (MUX - 4) of the chip; the
    conversion register then holds codes[chip][ain]; a stuck chip never finishes (OS 0)."""

    def __init__(self):
        self.codes = [[4800 + 4800 * c, 14400, 15200, 9600] for c in range(4)]
        self.conv = [0, 0, 0, 0]
        self.stuck = [False, False, False, False]
        self.fail = [False, False, False, False]
        self.writes = 0

    def writeto_mem(self, addr, reg, buf):
        c = addr - 0x48
        if self.fail[c]:
            raise OSError(19)
        self.writes += 1
        if reg == 1 and buf[0] & 0x80 and not self.stuck[c]:
            self.conv[c] = self.codes[c][(buf[0] >> 4) & 3] & 0xFFFF

    def readfrom_mem_into(self, addr, reg, buf):
        c = addr - 0x48
        if self.fail[c]:
            raise OSError(19)
        v = self.conv[c]
        if reg == 1:
            v = 0 if self.stuck[c] else 0x8000
        buf[0] = v >> 8
        buf[1] = v & 0xFF


class Pin:
    def __init__(self, v):
        self.v = v

    def value(self):
        return self.v


def _acquire_locked(fe, count):
    """fe.acquire() `count` times inside heap_lock; -1, or the index of the one that allocated."""
    micropython.heap_lock()
    try:
        for k in range(count):
            fe.acquire()
    except MemoryError:
        micropython.heap_unlock()
        return k
    micropython.heap_unlock()
    return -1


def _front_end(bus, rdy=None):
    fe = frontend.FrontEnd(REF, bus, 4, True, rdy, Pin(70000), Pin(0), Pin(1))
    assert fe.init()
    return fe


def test_driver_start_wait_read_allocate_nothing():
    def run():
        bus = FakeBus()
        bus.codes[0] = [1, -1, 32767, -32768]
        adc = ADS1115(bus, 0x48, 4096, 860)
        adc.init()
        got = [0, 0, 0, 0]
        bad = -1
        micropython.heap_lock()
        try:
            for k in range(100):
                adc.start(single(k & 3))
                if adc.wait_ready(2000):
                    got[k & 3] = adc.read_code()
        except MemoryError:
            bad = k
        micropython.heap_unlock()
        assert bad == -1, "ADS1115 start/wait_ready/read_code allocated at read %d" % bad
        assert got == [1, -1, 32767, -32768], got
    _with_clock(run)


def test_front_end_acquire_allocates_nothing_polling_os():
    def run():
        fe = _front_end(FakeBus())
        bad = _acquire_locked(fe, LOCKED)
        assert bad == -1, "FrontEnd.acquire allocated at record %d" % bad
        # ropes 1..4 at 4, 8, 12, 16 mA; displacements 12 mA; battery 15200 codes; temp 12 mA
        assert list(fe.rec) == [9600, 19200, 28800, 38400, 28800, 28800, 28800, 28800, 30400, 30400,
                                70000 & 0xFFFF, 1], list(fe.rec)
        assert fe.bus_errors == fe.timeouts == fe.rdy_timeouts == 0
    _with_clock(run)


def test_front_end_acquire_allocates_nothing_with_a_rdy_line():
    def run():
        bus = FakeBus()
        fe = _front_end(bus, Pin(1))
        bad = _acquire_locked(fe, LOCKED)
        assert bad == -1, "FrontEnd.acquire (RDY line) allocated at record %d" % bad
        assert list(fe.rec[:8]) == [9600, 19200, 28800, 38400, 28800, 28800, 28800, 28800]
    _with_clock(run)


def test_a_stuck_conversion_is_a_fault_without_allocation_or_hang():
    def run():
        bus = FakeBus()
        fe = _front_end(bus)
        bus.stuck[2] = True
        bad = _acquire_locked(fe, 20)
        assert bad == -1, "the timeout path allocated at record %d" % bad
        assert list(fe.rec[:8]) == [9600, 19200, 0, 38400, 28800, 28800, 0, 28800], list(fe.rec)
        assert fe.timeouts == 40 and fe.bus_errors == 0
        # a RDY line held low: bypassed by the OS bits, the values still come
        bus.stuck[2] = False
        fe = _front_end(bus, Pin(0))
        bad = _acquire_locked(fe, 20)
        assert bad == -1, "the RDY fallback allocated at record %d" % bad
        assert list(fe.rec[:4]) == [9600, 19200, 28800, 38400] and fe.rdy_timeouts == 41
    _with_clock(run)


def test_a_bus_error_is_a_sensor_fault_not_a_crash():
    def run():
        bus = FakeBus()
        fe = _front_end(bus)
        bus.fail[3] = True
        for _ in range(3):
            fe.acquire()
        assert list(fe.rec[:8]) == [9600, 19200, 28800, 0, 28800, 28800, 28800, 0], list(fe.rec)
        assert fe.bus_errors == 6
        bus.fail[3] = False
        fe.acquire()
        assert fe.rec[3] == 38400
    _with_clock(run)


def test_loop_words_and_namur_states():
    fs, sh = REF["fs_mv"], REF["shunt_ohm"]
    assert [boards.loop_ua(w, fs, sh) for w in (9600, 28800, 48000)] == [4000, 12000, 20000]
    assert boards.loop_state(8640, fs, sh) == boards.LOOP_OK       # 3.6 mA: the last good one
    assert boards.loop_state(8638, fs, sh) == boards.LOOP_LOW
    assert boards.loop_state(0, fs, sh) == boards.LOOP_LOW          # open loop
    assert boards.loop_state(50400, fs, sh) == boards.LOOP_OK      # 21 mA
    assert boards.loop_state(50402, fs, sh) == boards.LOOP_HIGH
