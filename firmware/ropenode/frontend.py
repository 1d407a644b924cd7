"""A board's sensor front end: ADS1115 conversions, encoder and Hall pins into one record.

    fe = FrontEnd(boards.get(), i2c, ropes, temp_fitted, rdy=pin, counter=c, hall_a=a, hall_b=b)
    fe.init()        # boot: set up the chips (bus errors counted, never raised)
    fe.acquire()     # each sample: fe.rec, array('H') of 2N+4 words in the .rsens order

Everything is injected (an I2C bus, pins, a counter: anything with their
methods), so the same code runs on the board, under CPython with fakes and
under the MicroPython unix port with fakes and heap_lock: `acquire` allocates
nothing and uses ints only.

The board table (ropenode.boards) says which chip and input each loop is on.
The loops are converted in rounds, each chip at most once a round, all chips
of a round in parallel: on the reference board round 1 is the four
pressures, round 2 the four displacements; battery and temperature (only
when fitted, else the word is 0xFFFF) take a third round once every
AUX_EVERY samples. A round starts each chip, sleeps one conversion time, then
waits for conversion ready (the shared ALERT/RDY line, or each chip's OS bit)
at most `wait_us` longer.

A loop that cannot be read reads word 0: a bus error (machine.I2C's OSError)
on its start or read, or a conversion not ready in time. Word 0 is below
every NAMUR lower limit (3.6 mA), so the node flags that rope's sample as a
sensor fault and never turns it into a tension; the other ropes go on. The
counters `bus_errors`, `timeouts` and `rdy_timeouts` saturate at COUNT_MAX
(small ints). A RDY line that does not rise is bypassed by OS-bit polling for
that round, and the chips are set up again at the next slow round (a chip
reset by a brown-out has lost its conversion-ready mode).
"""
import array
import time

from micropython import const

from ropenode.ads1115 import ADS1115, single
from ropenode.boards import WORD_SHIFT

AUX_EVERY = const(20)           # battery and temperature: one sample in 20
COUNT_MAX = const(0x3FFFFFFF)   # counters saturate here: small ints, never allocate


def _check(table, what, ch, used):
    chip, ain = ch
    if not 0 <= chip < len(table["ads"]) or not 0 <= ain <= 3:
        raise ValueError("board %s: chip %d AIN%d does not exist" % (what, chip, ain))
    if (chip, ain) in used:
        raise ValueError("board %s: chip %d AIN%d is already used" % (what, chip, ain))
    used.append((chip, ain))


def _word(a):
    """The stream word of chip a's conversion register: code << WORD_SHIFT, 0 for a code <= 0."""
    code = a.read_code()
    return code << WORD_SHIFT if code > 0 else 0


def _rounds(chans):
    """[(chip, ain, word)] into rounds, each a tuple of (chip, ain, word) with distinct chips."""
    rounds = []
    for c in chans:
        for r in rounds:
            if all(x[0] != c[0] for x in r):
                r.append(c)
                break
        else:
            rounds.append([c])
    return rounds


class FrontEnd:
    def __init__(self, table, i2c, ropes, temp_fitted=False, rdy=None, counter=None, hall_a=None, hall_b=None):
        if not 1 <= ropes <= len(table["pressure"]) or ropes > len(table["displacement"]):
            raise ValueError("board has loops for %d ropes, not %d" % (len(table["pressure"]), ropes))
        used = []
        fast = []
        for i in range(ropes):
            _check(table, "pressure", table["pressure"][i], used)
            fast.append(table["pressure"][i] + (i,))
        for i in range(ropes):
            _check(table, "displacement", table["displacement"][i], used)
            fast.append(table["displacement"][i] + (ropes + i,))
        _check(table, "battery", table["battery"], used)
        slow = [table["battery"] + (2 * ropes,)]
        if temp_fitted:
            _check(table, "temperature", table["temperature"], used)
            slow.append(table["temperature"] + (2 * ropes + 1,))
        self.rdy = rdy
        self.ads = [ADS1115(i2c, a, table["fs_mv"], table["sps"], rdy) for a in table["ads"]]
        self.chips = sorted(set(c for c, _ in used))   # the chips in use: init sets up only those

        def bind(r):
            return tuple((self.ads[c], single(ain), w) for c, ain, w in r)

        self.fast = tuple(bind(r) for r in _rounds(fast))
        self.slow = tuple(bind(r) for r in _rounds(slow))
        self.conv_us = self.ads[0].conversion_us
        self.wait_us = self.conv_us // 2
        self.counter = counter
        self.hall_a = hall_a
        self.hall_b = hall_b
        self.ropes = ropes
        self.rec = array.array("H", bytes(2 * (2 * ropes + 4)))
        self.rec[2 * ropes + 1] = 0xFFFF   # the temperature word when no input is fitted
        self._started = bytearray(len(self.rec))  # by word: 1 when its conversion started this round
        self._line = False                         # the RDY line rose this round
        self.k = 0                         # sample index modulo AUX_EVERY
        self.bus_errors = 0
        self.timeouts = 0
        self.rdy_timeouts = 0
        self._reinit = False

    def init(self):
        """Set up every chip in use; False if any did not answer (counted as a bus error)."""
        ok = True
        for c in self.chips:
            if not self._init_chip(c):
                ok = False
        return ok

    def _init_chip(self, c):
        try:
            self.ads[c].init()
            return True
        except OSError:
            self._bus_error()
            return False

    def _bus_error(self):
        if self.bus_errors < COUNT_MAX:
            self.bus_errors += 1

    # The per-sample methods below are split so that each one's frame (locals, value stack,
    # exception stack) fits in 11 words: a bigger bytecode frame is taken from the heap on
    # every call on ports without a pystack (tests/firmware/test_alloc_frames_cpython.py).

    def _convert(self, r):
        """One conversion on each (chip, mux, word) of round r, in parallel; 0 where one fails."""
        for i in range(len(r)):
            self._start(r[i])
        time.sleep_us(self.conv_us)
        self._line = self.rdy is not None and self._wait_rdy()
        for i in range(len(r)):
            self._read(r[i])

    def _start(self, ch):
        """Start channel ch = (chip, mux, word); its word reads 0 until it is read."""
        self.rec[ch[2]] = 0
        self._started[ch[2]] = 0
        try:
            ch[0].start(ch[1])
        except OSError:
            self._bus_error()
            return
        self._started[ch[2]] = 1

    def _wait_rdy(self):
        """True once the RDY line is high, False (counted, chips set up again at the next slow
        round) when it is not within wait_us."""
        t0 = time.ticks_us()
        while True:
            if self.rdy.value():
                return True
            if time.ticks_diff(time.ticks_us(), t0) >= self.wait_us:
                break
        self._reinit = True
        if self.rdy_timeouts < COUNT_MAX:
            self.rdy_timeouts += 1
        return False

    def _read(self, ch):
        """Read channel ch = (chip, mux, word) into its word if it started, once ready: the RDY
        line said so this round (_line), else the chip's OS bit within wait_us."""
        if not self._started[ch[2]]:
            return
        try:
            if self._line or ch[0].wait_ready(self.wait_us, True):
                self.rec[ch[2]] = _word(ch[0])
            elif self.timeouts < COUNT_MAX:
                self.timeouts += 1
        except OSError:
            self._bus_error()

    def acquire(self):
        """Fill self.rec with one record in the .rsens word order."""
        fast = self.fast
        for j in range(len(fast)):
            self._convert(fast[j])
        if self.k == 0:  # slow inputs: battery, temperature (if fitted)
            if self._reinit:
                self._reinit = False
                self.init()
            slow = self.slow
            for j in range(len(slow)):
                self._convert(slow[j])
        self._pins()
        k = self.k + 1  # wrapped: a count of all samples would pass 2**30 (62 days) and allocate
        self.k = 0 if k >= AUX_EVERY else k

    def _pins(self):
        """The encoder count and the Hall sensors into the record's last two words."""
        rec = self.rec
        n = self.ropes
        if self.counter is not None:
            rec[2 * n + 2] = self.counter.value() & 0xFFFF
        # Hall sensors pull low over a mark
        a = 0 if self.hall_a is None or self.hall_a.value() else 1
        b = 0 if self.hall_b is None or self.hall_b.value() else 2
        rec[2 * n + 3] = a | b
