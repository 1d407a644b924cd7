"""The ADS1115 driver, the board tables and the front end on a fake I2C bus (CPython).

The fake bus models the ADS1115's registers as the datasheet (TI SBAS444) gives
them: pointer 0 conversion, 1 config, 2 Lo_thresh, 3 Hi_thresh; a config write
with OS = 1 in single-shot mode starts a conversion of the input its MUX field
selects, OS reads 0 until it is done. The expected config words are built here
from the datasheet's bit positions, not from the driver's constants. Time is a
fake clock that advances with every tick read and sleep, so a chip that never
finishes shows as a timeout, not a hang. The same driver runs under the real
MicroPython with heap_lock in test_ads1115.py.
"""
from __future__ import annotations

import json
import shutil
import types
from pathlib import Path

import pytest

from ropemon.firmware import install_shim

install_shim()

from ropenode import ads1115, boards, frontend  # noqa: E402
from ropenode.ads1115 import ADS1115, single  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
# Datasheet tables: PGA[2:0] -> full scale (mV), DR[2:0] -> samples/s
PGA_MV = {0: 6144, 1: 4096, 2: 2048, 3: 1024, 4: 512, 5: 256}
DR_SPS = {0: 8, 1: 16, 2: 32, 3: 64, 4: 128, 5: 250, 6: 475, 7: 860}


class Clock:
    """time.ticks_us / ticks_diff / sleep_us: every tick read costs 20 us."""

    def __init__(self):
        self.us = 0

    def ticks_us(self):
        self.us += 20
        return self.us

    def ticks_diff(self, a, b):
        return a - b

    def sleep_us(self, us):
        self.us += us


@pytest.fixture(autouse=True)
def clock(monkeypatch):
    c = Clock()
    ns = types.SimpleNamespace(ticks_us=c.ticks_us, ticks_diff=c.ticks_diff, sleep_us=c.sleep_us)
    monkeypatch.setattr(ads1115, "time", ns)
    monkeypatch.setattr(frontend, "time", ns)
    return c


class Chip:
    def __init__(self):
        self.reg = {0: 0, 1: 0x8583, 2: 0x8000, 3: 0x7FFF}  # reset values
        self.busy = 0          # OS reads 0 for this many more config reads
        self.stuck = False     # a started conversion never finishes
        self.fail = False      # every transfer raises OSError (no ACK)
        self.fail_reads = False  # reads raise OSError, writes go through
        self.inputs = [0, 0, 0, 0]  # code of AIN0..3 against GND (signed)


class FakeBus:
    """ADS1115s at the given addresses, with machine.I2C's method signatures."""

    def __init__(self, addrs=(0x48, 0x49, 0x4A, 0x4B), busy_reads=1):
        self.chips = {a: Chip() for a in addrs}
        self.busy_reads = busy_reads
        self.log = []           # (op, addr, reg, value)
        self.buffers = set()    # ids of the buffers handed to the bus

    def _chip(self, addr):
        c = self.chips.get(addr)
        if c is None or c.fail:
            raise OSError(19)  # ENODEV: no ACK
        return c

    def writeto_mem(self, addr, memaddr, buf, *, addrsize=8):
        assert len(buf) == 2 and addrsize == 8
        self.buffers.add(id(buf))
        c = self._chip(addr)
        v = (buf[0] << 8) | buf[1]
        self.log.append(("w", addr, memaddr, v))
        if memaddr == 1:
            c.reg[1] = v & 0x7FFF
            mux = (v >> 12) & 7
            if v & 0x8000 and v & 0x0100:  # OS = 1 in single-shot: convert
                c.busy = self.busy_reads
                if mux >= 4 and not c.stuck:
                    c.reg[0] = c.inputs[mux - 4] & 0xFFFF
        else:
            c.reg[memaddr] = v

    def readfrom_mem_into(self, addr, memaddr, buf, *, addrsize=8):
        assert len(buf) == 2 and addrsize == 8
        self.buffers.add(id(buf))
        c = self._chip(addr)
        if c.fail_reads:
            raise OSError(5)  # EIO
        v = c.reg[memaddr]
        if memaddr == 1:
            if c.busy > 0 or c.stuck:
                c.busy -= 1
            else:
                v |= 0x8000
        self.log.append(("r", addr, memaddr, v))
        buf[0], buf[1] = v >> 8, v & 0xFF

    def scan(self):
        return sorted(a for a, c in self.chips.items() if not c.fail)


class FakePin:
    def __init__(self, v=1):
        self.v = v

    def value(self):
        return self.v


def config_word(os, mux, pga, mode_single, dr, comp):
    """The config register per the datasheet's field positions."""
    return os << 15 | mux << 12 | pga << 9 | mode_single << 8 | dr << 5 | comp


# --- the driver ---------------------------------------------------------------

@pytest.mark.parametrize("pga", sorted(PGA_MV))
@pytest.mark.parametrize("dr", sorted(DR_SPS))
def test_start_writes_the_config_word_for_each_input_gain_and_rate(pga, dr):
    bus = FakeBus()
    adc = ADS1115(bus, 0x49, fs_mv=PGA_MV[pga], sps=DR_SPS[dr])
    for ain in range(4):
        adc.start(single(ain))
        assert bus.log[-1] == ("w", 0x49, 1, config_word(1, 4 + ain, pga, 1, dr, 0b00011))
    for mux, k in ((ads1115.MUX_DIFF_0_1, 0), (ads1115.MUX_DIFF_0_3, 1), (ads1115.MUX_DIFF_1_3, 2),
                   (ads1115.MUX_DIFF_2_3, 3)):
        adc.start(mux)
        assert bus.log[-1] == ("w", 0x49, 1, config_word(1, k, pga, 1, dr, 0b00011))
    adc.continuous(single(3))
    assert bus.log[-1] == ("w", 0x49, 1, config_word(0, 7, pga, 0, dr, 0b00011))


def test_init_idles_the_chip_and_sets_conversion_ready_mode_with_a_rdy_pin():
    bus = FakeBus()
    ADS1115(bus, 0x48, 4096, 860).init()
    assert bus.log == [("w", 0x48, 1, config_word(0, 4, 1, 1, 7, 0b00011))]  # no OS: no conversion
    bus = FakeBus()
    adc = ADS1115(bus, 0x4B, 4096, 860, rdy=FakePin())
    adc.init()
    # Hi_thresh MSB 1, Lo_thresh MSB 0; COMP_POL 1 (active high), COMP_QUE 00 (pin enabled)
    assert bus.log == [("w", 0x4B, 2, 0x0000), ("w", 0x4B, 3, 0x8000),
                       ("w", 0x4B, 1, config_word(0, 4, 1, 1, 7, 0b01000))]
    adc.start(single(2))
    assert bus.log[-1] == ("w", 0x4B, 1, config_word(1, 6, 1, 1, 7, 0b01000))


def test_unknown_gain_or_rate_is_refused():
    with pytest.raises(ValueError, match="full scale"):
        ADS1115(FakeBus(), fs_mv=5000)
    with pytest.raises(ValueError, match="data rate"):
        ADS1115(FakeBus(), sps=100)


@pytest.mark.parametrize("raw,code", [(0x0000, 0), (0x0001, 1), (0x7FFF, 32767), (0x8000, -32768),
                                      (0xFFFF, -1), (0xFFFE, -2), (0x12C0, 4800)])
def test_conversion_register_is_twos_complement(raw, code):
    bus = FakeBus()
    bus.chips[0x48].reg[0] = raw
    assert ADS1115(bus).read_code() == code


def test_read_converts_the_selected_input_and_waits_for_os():
    bus = FakeBus(busy_reads=3)
    bus.chips[0x48].inputs = [100, -200, 300, 32767]
    adc = ADS1115(bus)
    assert [adc.read(single(k)) for k in range(4)] == [100, -200, 300, 32767]
    polls = [e for e in bus.log if e[0] == "r" and e[2] == 1]
    assert len(polls) == 4 * 4  # three busy polls, then ready, per read


def test_a_conversion_that_never_finishes_times_out_instead_of_hanging(clock):
    bus = FakeBus()
    bus.chips[0x48].stuck = True
    adc = ADS1115(bus)
    adc.start(single(0))
    t0 = clock.us
    assert adc.wait_ready(1000) is False
    assert 1000 <= clock.us - t0 < 1400
    with pytest.raises(OSError) as e:
        adc.read(single(0))
    assert e.value.args[0] == 110  # ETIMEDOUT (the errno on MicroPython)
    pin = FakePin(0)  # ALERT/RDY held low
    adc = ADS1115(FakeBus(), rdy=pin)
    assert adc.wait_ready(500) is False
    pin.v = 1
    assert adc.wait_ready(500) is True and adc.ready()


def test_bus_errors_reach_the_caller_as_oserror():
    bus = FakeBus()
    bus.chips[0x48].fail = True
    adc = ADS1115(bus)
    for call in (lambda: adc.start(single(0)), adc.read_code, adc.ready_os, adc.init):
        with pytest.raises(OSError):
            call()


def test_registers_go_through_two_preallocated_buffers():
    bus = FakeBus()
    adc = ADS1115(bus, rdy=None)
    adc.init()
    for k in range(50):
        adc.read(single(k % 4))
    assert bus.buffers == {id(adc._wbuf), id(adc._rbuf)}


# --- counts -> loop current, NAMUR NE43 ------------------------------------------

REF = boards.get("esp32-devkitc")


def word_of_ma(ma: float, fs_mv: int = 4096, shunt: int = 150) -> int:
    """Stream word of a loop current: the code of I x R at the datasheet's LSB, times 2."""
    return 2 * min(int(ma / 1000 * shunt / (fs_mv / 1000 / 32768) + 0.5), 32767)


@pytest.mark.parametrize("ma,word", [(4.0, 9600), (12.0, 28800), (20.0, 48000)])
def test_reference_board_words_at_4_12_20_ma(ma, word):
    assert word_of_ma(ma) == word
    assert boards.loop_ua(word, REF["fs_mv"], REF["shunt_ohm"]) == int(ma * 1000)
    assert boards.loop_state(word, REF["fs_mv"], REF["shunt_ohm"]) == boards.LOOP_OK


@pytest.mark.parametrize("ma,state", [(0.0, boards.LOOP_LOW), (2.0, boards.LOOP_LOW), (3.59, boards.LOOP_LOW),
                                      (3.6, boards.LOOP_OK), (3.8, boards.LOOP_OK), (20.5, boards.LOOP_OK),
                                      (21.0, boards.LOOP_OK), (21.01, boards.LOOP_HIGH),
                                      (22.5, boards.LOOP_HIGH), (30.0, boards.LOOP_HIGH)])
def test_namur_ne43_open_loop_and_over_range_are_faults(ma, state):
    assert boards.loop_state(word_of_ma(ma), REF["fs_mv"], REF["shunt_ohm"]) == state


@pytest.mark.parametrize("fs_mv,shunt", [(4096, 150), (6144, 250), (4096, 100), (2048, 100)])
def test_loop_current_is_exact_for_other_gains_and_shunts(fs_mv, shunt):
    for code in (0, 1, 4800, 12345, 32767):
        want = code * fs_mv * 1000 // 32768 // shunt  # uV / ohm = uA, floored
        assert boards.loop_ua(code << 1, fs_mv, shunt) == want


@pytest.fixture(scope="module")
def paper_node():
    from ropemon.cli import main as ropemon
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        for name in ("paper-site.toml", "paper-friction.json", "paper-compliance.json"):
            shutil.copy(ROOT / "scenarios" / name, Path(d) / name)
        assert ropemon(["config", str(Path(d) / "paper-site.toml"), "--out", str(Path(d) / "node.json")]) == 0
        return json.loads((Path(d) / "node.json").read_text())


def test_namur_state_agrees_with_the_node_fault_limits_commissioning_writes(paper_node):
    """Every word the reference board can produce (even: code x 2) is a NAMUR fault on the
    node (outside fault_lo..fault_hi of node.json) exactly when loop_state says so."""
    for ch in paper_node["node"]["pressure"] + paper_node["node"]["displacement"]:
        lo, hi = ch["fault_lo_counts"], ch["fault_hi_counts"]
        for w in range(0, 65535, 2):
            ok = boards.loop_state(w, REF["fs_mv"], REF["shunt_ohm"]) == boards.LOOP_OK
            assert ok == (lo <= w <= hi), (w, lo, hi)


# --- board tables ------------------------------------------------------------------

def _pins(t):
    return [t["i2c"][1], t["i2c"][2], t["encoder"][1], t["encoder"][2], *t["hall"], t["radio"][1], t["radio"][2]] + (
        [t["rdy"]] if t["rdy"] is not None else [])


@pytest.mark.parametrize("name", sorted(boards.BOARDS))
def test_every_board_table_is_complete_and_consistent(name):
    t = boards.get(name)
    pins = _pins(t)
    assert len(pins) == len(set(pins)), f"{name}: a pin used twice: {pins}"
    assert t["radio"][3] == 9600  # docs/protocol.md: the frame budget is for 9600 8N1
    assert len(set(t["ads"])) == len(t["ads"]) and all(0x48 <= a <= 0x4B for a in t["ads"])
    assert t["shunt_ohm"] * 21 * 1000 < ads1115.code_uv(32767, t["fs_mv"])  # 21 mA inside the range
    for ropes in range(1, 5):
        for temp in (False, True):
            fe = frontend.FrontEnd(t, FakeBus(t["ads"]), ropes, temp)
            assert len(fe.rec) == 2 * ropes + 4


def test_unknown_board_and_bad_tables_are_refused():
    with pytest.raises(ValueError, match="esp32-devkitc"):
        boards.get("arduino")
    bad = dict(REF, displacement=((0, 1), (1, 1), (2, 0), (3, 1)))  # chip 2 AIN0 is rope 3's pressure
    with pytest.raises(ValueError, match="already used"):
        frontend.FrontEnd(bad, FakeBus(), 4)
    bad = dict(REF, pressure=((0, 0), (1, 0), (4, 0), (3, 0)))
    with pytest.raises(ValueError, match="does not exist"):
        frontend.FrontEnd(bad, FakeBus(), 4)
    with pytest.raises(ValueError, match="4 ropes, not 5"):
        frontend.FrontEnd(REF, FakeBus(), 5)


# --- the front end --------------------------------------------------------------------

def _loaded_bus(addrs=(0x48, 0x49, 0x4A, 0x4B)):
    """Rope i's pressure on chip i AIN0 at 4 + 4i mA, displacement on AIN1 at 12 mA,
    battery (chip 0 AIN2) 1.9 V at the ADC, temperature (chip 1 AIN2) 8 mA."""
    bus = FakeBus(addrs)
    for i, a in enumerate(addrs):
        bus.chips[a].inputs = [word_of_ma(4 + 4 * i) // 2, word_of_ma(12) // 2, 0, 0]
    bus.chips[0x48].inputs[2] = 15200
    bus.chips[0x49].inputs[2] = word_of_ma(8) // 2
    return bus


@pytest.mark.parametrize("rdy", [None, FakePin(1)])
def test_front_end_fills_the_record_in_rsens_order(rdy):
    bus = _loaded_bus()
    t = dict(REF, rdy=None if rdy is None else 27)
    fe = frontend.FrontEnd(t, bus, 4, True, rdy=rdy, counter=FakePin(0x12345), hall_a=FakePin(0), hall_b=FakePin(1))
    assert fe.init()
    bus.log.clear()
    fe.acquire()
    assert list(fe.rec) == [9600, 19200, 28800, 38400, 28800, 28800, 28800, 28800, 30400, 19200, 0x2345, 1]
    # each round starts all four chips before reading any: they convert in parallel
    first = [e[0] for e in bus.log[:4]]
    assert first == ["w"] * 4 and {e[1] for e in bus.log[:4]} == {0x48, 0x49, 0x4A, 0x4B}
    polls = [e for e in bus.log if e[0] == "r" and e[2] == 1]
    assert (len(polls) == 0) == (rdy is not None)  # a RDY line saves the OS polls
    assert fe.bus_errors == fe.timeouts == fe.rdy_timeouts == 0


def test_temperature_word_is_0xffff_unless_fitted():
    fe = frontend.FrontEnd(REF, _loaded_bus(), 2, False)
    fe.acquire()
    assert fe.rec[5] == 0xFFFF and fe.rec[4] == 30400


def test_a_failing_chip_faults_its_rope_only_and_is_counted():
    bus = _loaded_bus()
    bus.chips[0x49].fail = True
    fe = frontend.FrontEnd(REF, bus, 4, True)
    assert not fe.init()
    fe.acquire()
    assert list(fe.rec[:8]) == [9600, 0, 28800, 38400, 28800, 0, 28800, 28800]
    assert fe.rec[9] == 0  # the temperature loop on that chip: below its NAMUR limit too
    assert fe.bus_errors > 0 and fe.timeouts == 0
    bus.chips[0x49].fail = False
    fe.acquire()
    assert list(fe.rec[:8]) == [9600, 19200, 28800, 38400, 28800, 28800, 28800, 28800]
    fe.bus_errors = frontend.COUNT_MAX - 1
    bus.chips[0x49].fail = True
    fe.acquire()
    assert fe.bus_errors == frontend.COUNT_MAX  # saturates: stays a small int


@pytest.mark.parametrize("rdy", [None, FakePin(1)])
def test_a_chip_that_fails_after_its_start_faults_its_rope_only(rdy):
    bus = _loaded_bus()
    fe = frontend.FrontEnd(dict(REF, rdy=None if rdy is None else 27), bus, 4, False, rdy=rdy)
    fe.init()
    fe.acquire()
    bus.chips[0x4B].fail_reads = True  # the start is acknowledged, the read is not
    fe.acquire()
    assert list(fe.rec[:8]) == [9600, 19200, 28800, 0, 28800, 28800, 28800, 0]
    assert fe.bus_errors == 2 and fe.timeouts == 0


def test_a_stuck_conversion_faults_its_rope_after_a_bounded_wait(clock):
    bus = _loaded_bus()
    bus.chips[0x4A].stuck = True
    fe = frontend.FrontEnd(REF, bus, 4, False)
    fe.init()
    t0 = clock.us
    fe.acquire()
    assert list(fe.rec[:8]) == [9600, 19200, 0, 38400, 28800, 28800, 0, 28800]
    assert fe.timeouts == 2 and fe.bus_errors == 0
    assert clock.us - t0 < 2 * (2 * fe.conv_us + 2 * fe.wait_us) + 6000  # bounded: no hang


def test_a_rdy_line_that_stays_low_falls_back_to_os_and_reinits_the_chips():
    bus = _loaded_bus()
    line = FakePin(0)
    fe = frontend.FrontEnd(dict(REF, rdy=27), bus, 4, False, rdy=line)
    fe.init()
    fe.k = 1  # not a slow round
    fe.acquire()
    assert list(fe.rec[:4]) == [9600, 19200, 28800, 38400]  # read by OS polling
    assert fe.rdy_timeouts == 2 and fe.timeouts == 0
    for c in bus.chips.values():
        c.reg[2], c.reg[3] = 0x8000, 0x7FFF  # as after a brown-out reset
    fe.k = 0
    line.v = 1
    fe.acquire()  # slow round: the chips are set up again
    assert all((c.reg[2], c.reg[3]) == (0, 0x8000) for c in bus.chips.values())


def test_slow_inputs_are_read_one_sample_in_20_and_the_counter_wraps():
    fe = frontend.FrontEnd(REF, _loaded_bus(), 2, True)
    seen = 0
    for _ in range(1000):
        fe.rec[4] = 0
        fe.acquire()
        seen += fe.rec[4] != 0
        assert 0 <= fe.k < frontend.AUX_EVERY
    assert seen == 50


def test_a_bus_error_makes_that_ropes_sample_a_sensor_fault_on_the_node():
    """End to end: chip 0x49 (rope 2) stops answering mid-window; the node's frame flags
    rope 2's pressure and displacement as faulted, the other ropes stay healthy."""
    from firmware_rig import node_doc
    from ropenode import config, layout
    from ropenode.node import K, Node

    cfg = config.parse(node_doc())
    node = Node(cfg)
    bus = _loaded_bus()
    for a in bus.chips:  # every rope near mid-range: 10 mA pressure, 12 mA displacement
        bus.chips[a].inputs[0] = word_of_ma(10) // 2
    fe = frontend.FrontEnd(REF, bus, cfg.ropes, False, counter=FakePin(0), hall_a=FakePin(1), hall_b=FakePin(1))
    fe.init()
    frames = []
    for k in range(3 * cfg.window):
        bus.chips[0x49].fail = k >= cfg.window
        fe.acquire()
        if node.sample(fe.rec):
            frames.append(node.S[K.OUT_FAULTS])
            buf = bytearray(layout.MAX_WIRE_LEN)
            node.frame_into(buf)
    assert frames[0] == 0
    assert frames[1] == frames[2] == (1 << 1) | (16 << 1)  # bit i pressure, 4 + i displacement


def test_driver_and_front_end_ints_stay_within_small_int_range():
    """The AST range instrumentation of test_int32_ast_cpython.py over the driver, the front
    end and the loop conversions: codes at both rails, every stream word, every full scale
    and the shunts of the tables; no intermediate leaves +-2**30, no float appears."""
    from test_int32_ast_cpython import instrumented_firmware

    with instrumented_firmware() as monitor:
        from ropenode import ads1115 as a2, boards as b2, frontend as f2
        clock = Clock()
        a2.time = f2.time = types.SimpleNamespace(ticks_us=clock.ticks_us, ticks_diff=clock.ticks_diff,
                                                  sleep_us=clock.sleep_us)
        bus = _loaded_bus()
        bus.chips[0x48].inputs = [32767, -32768, 32767, 0]
        bus.chips[0x4A].stuck = True
        fe = f2.FrontEnd(REF, bus, 4, True, counter=FakePin((1 << 29) + 12345), hall_a=FakePin(0), hall_b=FakePin(0))
        fe.init()
        fe.bus_errors = fe.timeouts = f2.COUNT_MAX - 3
        monitor.armed = True
        try:
            for _ in range(45):
                fe.acquire()
            for fs in (6144, 4096, 2048, 1024, 512, 256):
                for code in (-32768, -1, 0, 1, 32767):
                    a2.code_uv(code, fs)
                for shunt in {t["shunt_ohm"] for t in b2.BOARDS.values()} | {250}:
                    for w in range(0, 65536, 97):
                        b2.loop_ua(w, fs, shunt)
                        b2.loop_state(w, fs, shunt)
        finally:
            monitor.armed = False
        assert fe.rec[0] == 65534 and fe.rec[4] == 0 and fe.timeouts == f2.COUNT_MAX
    assert monitor.checked > 10000
    assert any("ads1115.py" in loc for loc in monitor.peak) and any("frontend.py" in loc for loc in monitor.peak)
