"""Board HAL for the reference cage node: ESP32 + four ADS1115 ADCs + radio on a UART.

Wiring (docs/model.md, "Reference hardware"):
    I2C0  SCL GPIO22, SDA GPIO21, 400 kHz; ADS1115 at 0x48, 0x49, 0x4A, 0x4B
          chip i: AIN0 = pressure loop of rope i, AIN1 = displacement loop of rope i;
          chip 0 AIN2 = battery divider, chip 1 AIN2 = oil temperature loop (if fitted:
          config temperature.fitted; read only then, else the word is 0xFFFF)
          each 4-20 mA loop across a 150 ohm 0.1 % shunt: 4 mA = 0.6 V, PGA +-4.096 V
    speed encoder  pulses GPIO25, direction GPIO26 -> machine.Counter (up/down)
    Hall pair      GPIO32 (sensor A), GPIO33 (sensor B), low = over a mark
    radio          UART1 TX GPIO17, RX GPIO16, 9600 8N1
Stream counts are ADS1115 codes (0..32767 for 0..4.096 V) times 2, so the
words match the 16-bit .rsens format (4 mA = 9600, 20 mA = 48000 counts).

A Timer fires at sample_hz; its callback only sets a flag (and counts a
missed tick when the flag is still set). The main loop does the I2C reads into
preallocated buffers, calls node.sample and sends a frame when a window
closes. The watchdog is fed only while samples keep being processed on time.
The frame seq continues across resets through the boot counter in /bootcount
(ropenode.bootseq). When armed (/record, `ropemon record`), the raw records of
the first seconds after boot also go to /wind.rsens (ropenode.rsens), for the
compliance fit of a commissioning wind.
"""
import array
import gc
import time

import machine
from machine import I2C, UART, WDT, Counter, Pin, Timer
from micropython import const

from ropenode import layout, rsens
from ropenode.bootseq import FrameSeq

BOOT_FILE = "/bootcount"
_frame_seq = None  # one per boot: a restarted run() (main.py) continues it, no extra flash write

_ADS_ADDRS = (0x48, 0x49, 0x4A, 0x4B)
_REG_CONV = const(0)
_REG_CONFIG = const(1)
# OS=1 start, PGA +-4.096 V (001), single shot, 860 SPS (111), comparator off (11)
_CFG_BASE = const(0x8000 | 0x0200 | 0x0100 | 0x00E0 | 0x0003)
_SHUNT_OHM = const(150)         # each 4-20 mA loop's shunt to ground: 4 mA = 0.6 V, 20 mA = 3.0 V
_WORD_SHIFT = const(1)          # stream word = ADS1115 code << 1 (0..32767 -> 0..65534)
_CONV_US = const(1300)          # one 860 SPS conversion plus margin
_AUX_EVERY = const(20)          # battery and temperature: one sample in 20
_WDT_MS = const(2000)
_HEALTHY_MS = const(500)        # fed only if a sample was processed this recently
_COUNT_MAX = const(0x3FFFFFFF)  # diagnostic counters saturate here: stay small ints, never allocate


def _cfg_bytes(ain):
    c = _CFG_BASE | ((4 + ain) << 12)  # MUX 1xx: AINx against GND
    return bytes(((c >> 8) & 0xFF, c & 0xFF))


class Board:
    """Owns the peripherals; `run_forever` is the node's main loop."""

    def __init__(self, node, ropes, sample_hz, temp_fitted=False):
        self.node = node
        self.ropes = ropes
        self.sample_hz = sample_hz
        self.temp_fitted = temp_fitted
        self.i2c = I2C(0, scl=Pin(22), sda=Pin(21), freq=400_000)
        self.uart = UART(1, baudrate=9600, tx=Pin(17), rx=Pin(16))
        self.counter = Counter(0, Pin(25, Pin.IN), direction=Pin(26, Pin.IN))
        self.hall_a = Pin(32, Pin.IN, Pin.PULL_UP)
        self.hall_b = Pin(33, Pin.IN, Pin.PULL_UP)
        self.cfg_ain = [_cfg_bytes(a) for a in range(4)]
        self.conv = bytearray(2)
        self.rec = array.array("H", [0] * (2 * ropes + 4))
        self.rec[2 * ropes + 1] = 0xFFFF  # the temperature word when no input is fitted
        self.wire = bytearray(layout.MAX_WIRE_LEN)
        self.wire_mv = memoryview(self.wire)
        self.tick = False
        self.missed = 0
        self.k = 0                # sample index modulo _AUX_EVERY
        self.last_ok_ms = time.ticks_ms()
        self.i2c_errors = 0
        self.timer = Timer(0)
        self.wdt: WDT | None = None
        self.recorder: rsens.Writer | None = None  # an armed recording (_recorder)

    def _bus_error(self):
        if self.i2c_errors < _COUNT_MAX:
            self.i2c_errors += 1

    def _on_timer(self, _t):
        # Interrupt context: no allocation, no I2C. Only flags. (missed is cleared every loop.)
        if self.tick and self.missed < _COUNT_MAX:
            self.missed += 1
        self.tick = True

    def _start(self, chip, ain):
        self.i2c.writeto_mem(_ADS_ADDRS[chip], _REG_CONFIG, self.cfg_ain[ain])

    def _read(self, chip):
        """The chip's last conversion as stream counts (0..65534); 0 on a bus error."""
        try:
            self.i2c.readfrom_mem_into(_ADS_ADDRS[chip], _REG_CONV, self.conv)
        except OSError:
            self._bus_error()
            return 0  # reads as a failed loop (below 3.6 mA): flagged, never a tension
        v = (self.conv[0] << 8) | self.conv[1]
        if v & 0x8000:
            return 0
        return v << _WORD_SHIFT

    def _convert(self, ain, words, first):
        """One conversion of input `ain` on every rope's chip, in parallel."""
        n = self.ropes
        for i in range(n):
            try:
                self._start(i, ain)
            except OSError:
                self._bus_error()
        time.sleep_us(_CONV_US)
        for i in range(n):
            words[first + i] = self._read(i)

    def acquire(self):
        """Fill self.rec with one record in the .rsens word order."""
        n = self.ropes
        rec = self.rec
        self._convert(0, rec, 0)      # pressures
        self._convert(1, rec, n)      # displacements
        if self.k == 0:  # slow inputs: battery, temperature (if fitted)
            temp = self.temp_fitted
            try:
                self._start(0, 2)
                if temp:
                    self._start(1, 2)
            except OSError:
                self._bus_error()
            time.sleep_us(_CONV_US)
            rec[2 * n] = self._read(0)
            if temp:
                rec[2 * n + 1] = self._read(1)
        rec[2 * n + 2] = self.counter.value() & 0xFFFF
        # Hall sensors pull low over a mark
        rec[2 * n + 3] = (0 if self.hall_a.value() else 1) | (0 if self.hall_b.value() else 2)
        k = self.k + 1  # wrapped: a count of all samples would pass 2**30 (62 days) and allocate
        self.k = 0 if k >= _AUX_EVERY else k

    def run_forever(self):
        node = self.node
        if machine.reset_cause() == machine.WDT_RESET:
            node.sticky_status |= layout.ST_WATCHDOG_RESET
        self.wdt = WDT(timeout=_WDT_MS)
        self.timer.init(mode=Timer.PERIODIC, freq=self.sample_hz, callback=self._on_timer)
        while True:
            if not self.tick:
                self._feed_if_healthy()
                continue
            self.tick = False
            self.step()

    def step(self):
        """One timer tick's work: acquire, record (if armed), compensate, frame, feed."""
        node = self.node
        if self.missed:
            self.missed = 0
            node.pending_status |= layout.ST_OVERRUN
        self.acquire()
        if self.recorder is not None:
            self._record(self.recorder)
        if node.sample(self.rec):
            n = node.frame_into(self.wire)
            self.uart.write(self.wire_mv[:n])
            # frame_into leaves ~1 KB of garbage (struct, SHA-256): collect it now, between
            # samples, rather than let an automatic collection land in a later sample.
            gc.collect()
        self.last_ok_ms = time.ticks_ms()
        self._feed_if_healthy()

    def _record(self, rec: rsens.Writer) -> None:
        """Append this record to the armed recording `rec`; drop it once it is done, or when
        the flash fails (full): the node goes on monitoring either way."""
        try:
            if not rec.add(self.rec):
                self.recorder = None
                print("ropenode: recorded", rsens.RECORD_FILE)
        except OSError as e:
            self.recorder = None
            print("ropenode: recording stopped:", e)
            try:
                rec.close()
            except OSError:
                pass

    def _feed_if_healthy(self):
        if time.ticks_diff(time.ticks_ms(), self.last_ok_ms) < _HEALTHY_MS and self.wdt is not None:
            self.wdt.feed()


def _load_config(config_path):
    """(cfg, node_id, key, reason) from config.load_for_boot, with ropenode.config released.

    Only plain data leave: a Config (its class has no methods, so it keeps
    none of config.py's code or globals), ints, bytes and the reason string
    (never a ConfigError). Once this returns, its locals (the module) are gone
    and the caller's gc.collect() frees the validator's code.
    """
    from ropenode import config

    # Missing, unreadable or refused: keep running, say so, and sign the
    # config-fault frames with the file's identity where it is still valid.
    cfg, node_id, key, reason = config.load_for_boot(config_path)
    config.release()
    return cfg, node_id, key, reason


def _boot(config_path):
    """Load and validate the config, release ropenode.config, then build the Node.

    The validator is needed at boot only, and loaded from a .mpy file (not
    frozen) its bytecode takes ~11 KB of RAM. It is released (config.release)
    and collected before ropenode.node (kernel, frame, ...) is imported, so the
    boot peak never holds both the validator's code and the node's: the order
    keeps that peak under the 32 KiB budget (docs/benchmarks.md). The Config
    left over is freed by the caller's gc.collect() once this returns.
    Returns (node, ropes, sample_hz, temp_fitted).
    """
    cfg, node_id, key, reason = _load_config(config_path)
    gc.collect()  # frees ropenode.config's code: only the Config (plain data) is left
    from ropenode.node import Node

    node = Node(cfg, node_id, key, seq=_frame_seq)  # never given a ConfigError: plain data only
    if cfg is None:
        print("ropenode:", reason, "- config-fault status frames as node", node_id)
        return node, 4, 200, False
    return node, cfg.ropes, cfg.sample_hz, cfg.fitted == 1


def run(config_path="/node.json", boot_file=BOOT_FILE):
    """Boot: load and validate the config, then sample forever (status frames if invalid)."""
    global _frame_seq
    if _frame_seq is None:
        _frame_seq = FrameSeq(boot_file)
    node, ropes, sample_hz, fitted = _boot(config_path)
    gc.collect()  # frees the Config and the build's garbage: nothing refers to them now
    board = Board(node, ropes, sample_hz, fitted)
    board.recorder = _recorder(ropes, sample_hz)
    board.run_forever()


def _recorder(ropes, sample_hz, root="/"):
    """The Writer of an armed recording (rsens.RECORD_FLAG, removed now so that a reset does
    not start it again), or None when not armed or the flash refuses."""
    import os

    seconds = rsens.armed_seconds(root + rsens.RECORD_FLAG)
    if not seconds:
        return None
    try:
        os.remove(root + rsens.RECORD_FLAG)
        f = open(root + rsens.RECORD_FILE, "wb")
    except OSError as e:
        print("ropenode: cannot record:", e)
        return None
    print("ropenode: recording", seconds, "s of samples to", root + rsens.RECORD_FILE)
    return rsens.Writer(f, ropes, sample_hz, seconds * sample_hz)
