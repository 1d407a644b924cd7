"""Board HAL of a cage node: the board table's buses, the sample loop, the radio.

    hal_board.run("/node.json")                   # main.py: the board of boards.BOARD
    hal_board.run("/node.json", board="esp32s3-devkitc")
    from ropenode import bringup; bringup.bench()  # bring-up at the REPL (docs/hardware.md)

Pins and buses come from one table (ropenode.boards; the reference board and
its wiring: docs/hardware.md), so another board is a new table, not a new
HAL. `Board` builds the machine objects the table names unless they are
given (constructor injection: tests pass a fake I2C bus, UART and pins). The
ADS1115 front end (ropenode.frontend, ropenode.ads1115) fills the record:
stream counts are ADS1115 codes times 2, so the words match the 16-bit .rsens
format (reference board: 4 mA = 9600, 20 mA = 48000 counts); a loop that
cannot be read (bus error, conversion not ready) reads 0, a NAMUR fault of
that rope's sample, never a crash.

A Timer fires at sample_hz; its callback only sets a flag (and counts a
missed tick when the flag is still set). The main loop does the I2C reads into
preallocated buffers, calls node.sample and sends a frame when a window
closes. The watchdog (2 s) is fed only while samples keep being processed on time.
Ctrl-C (someone at the REPL, or mpremote) opens a maintenance window: `maintenance`
re-arms the watchdog with the board's wdt_maintenance_ms (ropenode.boards), says so,
and the KeyboardInterrupt goes on to the REPL; nothing feeds the watchdog there, so
the node resets and samples again at the end of the window unless reset before.
The frame seq continues across resets through the boot counter in /bootcount
(ropenode.bootseq). When armed (/record, `ropemon record`), the raw records of
the first seconds after boot also go to /wind.rsens (ropenode.rsens), for the
compliance fit of a commissioning wind.
"""
import gc
import time

import machine
from machine import I2C, UART, WDT, Counter, Pin, Timer
from micropython import const

from ropenode import layout, rsens
from ropenode.bootseq import FrameSeq

BOOT_FILE = "/bootcount"
_frame_seq = None  # one per boot: a restarted run() (main.py) continues it, no extra flash write
_maint_ms = 0      # while this boot's sampling watchdog runs: the board's maintenance timeout; else 0

_WDT_MS = const(2000)
_HEALTHY_MS = const(500)        # fed only if a sample was processed this recently
_COUNT_MAX = const(0x3FFFFFFF)  # diagnostic counters saturate here: stay small ints, never allocate


class Board:
    """Owns the peripherals; `run_forever` is the node's main loop.

    `table`: a board table (default boards.get()); `i2c`, `uart`, `rdy`, `counter`,
    `hall` (a pair of pins): given ones are used as they are, the others are built
    from the table with machine."""

    def __init__(self, node, ropes, sample_hz, temp_fitted=False, table=None, i2c=None, uart=None,
                 rdy=None, counter=None, hall=None):
        # imported here, not at the top: main.py imports this module before the boot
        # parses node.json, and the boot peak of the heap must not hold them too
        from ropenode import boards
        from ropenode.frontend import FrontEnd

        t = boards.get() if table is None else table
        self.table = t
        self.maint_ms = boards.maintenance_ms(t)
        self.node = node
        self.ropes = ropes
        self.sample_hz = sample_hz
        self.temp_fitted = temp_fitted
        if i2c is None:
            bus, scl, sda, hz = t["i2c"]
            i2c = I2C(bus, scl=Pin(scl), sda=Pin(sda), freq=hz)
        if uart is None:
            uid, tx, rx, baud = t["radio"]
            uart = UART(uid, baudrate=baud, bits=8, parity=None, stop=1, tx=Pin(tx), rx=Pin(rx))
        if rdy is None and t["rdy"] is not None:
            rdy = Pin(t["rdy"], Pin.IN, Pin.PULL_UP)
        if counter is None:
            cid, pulses, direction = t["encoder"]
            counter = Counter(cid, Pin(pulses, Pin.IN), direction=Pin(direction, Pin.IN))
        if hall is None:
            hall = (Pin(t["hall"][0], Pin.IN, Pin.PULL_UP), Pin(t["hall"][1], Pin.IN, Pin.PULL_UP))
        self.i2c = i2c
        self.uart = uart
        self.fe = FrontEnd(t, i2c, ropes, temp_fitted, rdy, counter, hall[0], hall[1])
        self.fe.init()
        self.rec = self.fe.rec
        self.wire = bytearray(layout.MAX_WIRE_LEN)
        self.wire_mv = memoryview(self.wire)
        self.tick = False
        self.missed = 0
        self.last_ok_ms = time.ticks_ms()
        self.timer: Timer | None = None
        self.wdt: WDT | None = None
        self.recorder: rsens.Writer | None = None  # an armed recording (_recorder)

    def _on_timer(self, _t):
        # Interrupt context: no allocation, no I2C. Only flags. (missed is cleared every loop.)
        if self.tick and self.missed < _COUNT_MAX:
            self.missed += 1
        self.tick = True

    def acquire(self):
        """Fill self.rec with one record in the .rsens word order (ropenode.frontend)."""
        self.fe.acquire()

    def run_forever(self):
        """Sample until Ctrl-C: then the maintenance window (`maintenance`) and the
        KeyboardInterrupt goes on (to main.py, then the REPL)."""
        global _maint_ms
        node = self.node
        if machine.reset_cause() == machine.WDT_RESET:
            node.sticky_status |= layout.ST_WATCHDOG_RESET
        _maint_ms = self.maint_ms  # before the watchdog starts: a Ctrl-C from here on opens the window
        self.wdt = WDT(timeout=_WDT_MS)
        timer = self.timer = Timer(0)
        timer.init(mode=Timer.PERIODIC, freq=self.sample_hz, callback=self._on_timer)
        try:
            while True:
                if not self.tick:
                    self._feed_if_healthy()
                    continue
                self.tick = False
                self.step()
        except KeyboardInterrupt:
            self.wdt = maintenance()  # first thing: the 2 s watchdog is still counting
            timer.deinit()
            raise

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
        the flash fails (full): the node goes on monitoring either way. Runs every sample
        while armed, so its frame stays within 11 words (no `except ... as e`: that costs a
        second exception level, a heap frame on every call; tools/check_frame_spill.py)."""
        try:
            if rec.add(self.rec):
                return
        except OSError:
            self._stop_recording(rec)
            return
        self.recorder = None
        print("ropenode: recorded", rsens.RECORD_FILE)

    def _stop_recording(self, rec: rsens.Writer) -> None:
        """The flash refused a write of the recording: drop it and close its file."""
        self.recorder = None
        print("ropenode: recording stopped: a flash write failed")
        try:
            rec.close()
        except OSError:
            pass

    def _feed_if_healthy(self):
        if time.ticks_diff(time.ticks_ms(), self.last_ok_ms) < _HEALTHY_MS and self.wdt is not None:
            self.wdt.feed()


def maintenance():
    """Open the maintenance window: re-arm the watchdog with the board's maintenance timeout
    and print so. Called on Ctrl-C (Board.run_forever, main.py); does nothing unless this
    boot's run_forever has started the sampling watchdog, and only once. Returns the WDT,
    or None. Nothing feeds it afterwards: the node resets at the end of the window (a
    watchdog reset: frames flag it) unless reset before; a soft reset (mpremote) does not
    stop it. Never raises but KeyboardInterrupt: the caller's Ctrl-C must reach the REPL."""
    global _maint_ms
    ms = _maint_ms
    if not ms:
        return None
    _maint_ms = 0
    try:
        wdt = WDT(timeout=ms)  # esp32: reconfigures the running task watchdog (esp_task_wdt_reconfigure)
    except Exception as e:
        print("ropenode: the watchdog refused", ms, "ms:", e, "- the node resets within 2 s")
        return None
    print("ropenode: MAINTENANCE: sampling stopped; the watchdog resets the node in", ms // 1000,
          "s unless it is reset before")
    return wdt


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


def run(config_path="/node.json", boot_file=BOOT_FILE, board=None):
    """Boot: load and validate the config, then sample forever (status frames if invalid).
    `board`: a name in ropenode.boards (default boards.BOARD)."""
    global _frame_seq
    if _frame_seq is None:
        _frame_seq = FrameSeq(boot_file)
    node, ropes, sample_hz, fitted = _boot(config_path)
    gc.collect()  # frees the Config and the build's garbage: nothing refers to them now
    from ropenode import boards

    hal = Board(node, ropes, sample_hz, fitted, boards.get(board))
    hal.recorder = _recorder(ropes, sample_hz)
    hal.run_forever()


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

