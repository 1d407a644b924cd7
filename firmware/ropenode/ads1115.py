"""TI ADS1115 16-bit I2C ADC (datasheet SBAS444), in the manner of micropython-lib drivers.

    from machine import I2C, Pin
    adc = ADS1115(I2C(0, scl=Pin(22), sda=Pin(21), freq=400_000), 0x48, fs_mv=4096, sps=860)
    adc.init()
    code = adc.read(single(0))            # start, wait, read: -32768..32767 (OSError on a timeout)

    adc.start(single(0))                  # or split, as the board HAL does for 4 chips in parallel:
    time.sleep_us(adc.conversion_us)
    if adc.wait_ready(500):
        code = adc.read_code()

The bus is injected (anything with machine.I2C's `writeto_mem` and
`readfrom_mem_into`), so a test passes a fake one. Registers go through two
preallocated 2-byte buffers: start, ready and read_code allocate nothing and
use ints only (every value below 2**17). A bus error is machine.I2C's OSError,
left to the caller.

Registers (pointer byte): 0 conversion, 1 config, 2 Lo_thresh, 3 Hi_thresh.
Config word: OS[15] MUX[14:12] PGA[11:9] MODE[8] DR[7:5] COMP_MODE[4]
COMP_POL[3] COMP_LAT[2] COMP_QUE[1:0].

Conversion ready: by the OS bit (read of the config register: 1 = not
converting), or by an ALERT/RDY pin (`rdy`, a machine.Pin input with a
pull-up). With `rdy`, `init` puts ALERT/RDY in conversion-ready mode
(Hi_thresh MSB 1, Lo_thresh MSB 0, COMP_QUE 00) active high (COMP_POL 1): in
single-shot mode the open-drain pin then follows the OS bit, low while
converting. Several chips' ALERT/RDY wired to one pull-up read high only when
every one of them is done (the board HAL shares one line among its chips).
In continuous mode the pin gives an 8 us pulse per conversion instead: use the
OS bit or the data rate there.
"""
import time

from micropython import const

REG_CONVERSION = const(0)
REG_CONFIG = const(1)
REG_LO_THRESH = const(2)
REG_HI_THRESH = const(3)

OS = const(0x8000)              # write 1: start a single-shot conversion; read 1: not converting
MUX_DIFF_0_1 = const(0x0000)    # AIN0 - AIN1 (reset value)
MUX_DIFF_0_3 = const(0x1000)
MUX_DIFF_1_3 = const(0x2000)
MUX_DIFF_2_3 = const(0x3000)
MUX_SINGLE_0 = const(0x4000)    # AIN0 - GND; AINx is MUX_SINGLE_0 + (x << 12), see single()
PGA_6144 = const(0x0000)        # +-6.144 V full scale
PGA_4096 = const(0x0200)
PGA_2048 = const(0x0400)        # reset value
PGA_1024 = const(0x0600)
PGA_512 = const(0x0800)
PGA_256 = const(0x0A00)         # 0x0C00, 0x0E00 are +-0.256 V too
MODE_CONTINUOUS = const(0x0000)
MODE_SINGLE = const(0x0100)     # single-shot, power-down between conversions (reset value)
DR_8 = const(0x0000)
DR_16 = const(0x0020)
DR_32 = const(0x0040)
DR_64 = const(0x0060)
DR_128 = const(0x0080)          # reset value
DR_250 = const(0x00A0)
DR_475 = const(0x00C0)
DR_860 = const(0x00E0)
COMP_POL_HIGH = const(0x0008)   # ALERT/RDY active high
COMP_QUE_1 = const(0x0000)      # comparator (and the RDY function) on, assert after 1 conversion
COMP_DISABLE = const(0x0003)    # COMP_QUE 11: comparator off, ALERT/RDY high impedance (reset value)

# Full-scale range in mV and data rate in samples/s, indexed by PGA[2:0] and DR[2:0]
FULL_SCALE_MV = (6144, 4096, 2048, 1024, 512, 256, 256, 256)
RATES_SPS = (8, 16, 32, 64, 128, 250, 475, 860)

_ETIMEDOUT = const(110)


def single(ain):
    """MUX bits of input AINx (0..3) against GND."""
    return MUX_SINGLE_0 + (ain << 12)


def pga_bits(fs_mv):
    """PGA bits of a full-scale range in mV (6144, 4096, ... 256)."""
    for k in range(6):
        if FULL_SCALE_MV[k] == fs_mv:
            return k << 9
    raise ValueError("ADS1115 full scale %d mV: not one of 6144..256" % fs_mv)


def dr_bits(sps):
    """DR bits of a data rate in samples/s (8, 16, ... 860)."""
    for k in range(8):
        if RATES_SPS[k] == sps:
            return k << 5
    raise ValueError("ADS1115 data rate %d SPS: not one of 8..860" % sps)


def conversion_us(sps):
    """Single-shot conversion time: one period 10 % long (the internal oscillator's
    tolerance, datasheet) plus 50 us of wake-up from power-down."""
    return 1_000_000 // sps * 11 // 10 + 50


def code_uv(code, fs_mv):
    """Input voltage in uV of a conversion code at full scale `fs_mv`: code x FS / 32768,
    floored (exact at +-4.096 V and +-2.048 V). Every full scale is a multiple of 32 mV,
    so no product passes 2**30."""
    return code * (fs_mv >> 5) * 125 // 128


class ADS1115:
    def __init__(self, i2c, address=0x48, fs_mv=4096, sps=860, rdy=None):
        self.i2c = i2c
        self.address = address
        self.fs_mv = fs_mv
        self.rdy = rdy
        self.conversion_us = conversion_us(sps)
        comp = COMP_POL_HIGH | COMP_QUE_1 if rdy is not None else COMP_DISABLE
        self._base = pga_bits(fs_mv) | dr_bits(sps) | comp
        self._wbuf = bytearray(2)
        self._rbuf = bytearray(2)

    def _write(self, reg, value):
        b = self._wbuf
        b[0] = (value >> 8) & 0xFF
        b[1] = value & 0xFF
        self.i2c.writeto_mem(self.address, reg, b)

    def _read(self, reg):
        """The register as an unsigned 16-bit int."""
        b = self._rbuf
        self.i2c.readfrom_mem_into(self.address, reg, b)
        return (b[0] << 8) | b[1]

    def init(self):
        """Set up the chip, idle (power-down, no conversion); with `rdy`, ALERT/RDY in
        conversion-ready mode. Call again after the chip may have been reset (brown-out):
        the thresholds are back at their reset values then."""
        if self.rdy is not None:
            self._write(REG_LO_THRESH, 0x0000)
            self._write(REG_HI_THRESH, 0x8000)
        self._write(REG_CONFIG, self._base | MODE_SINGLE | MUX_SINGLE_0)

    def config(self):
        """The config register as read back (unsigned 16-bit)."""
        return self._read(REG_CONFIG)

    def start(self, mux):
        """Start one single-shot conversion of `mux` (MUX_* or single(x))."""
        self._write(REG_CONFIG, OS | self._base | MODE_SINGLE | mux)

    def continuous(self, mux):
        """Convert `mux` continuously at the data rate; read_code gives the latest."""
        self._write(REG_CONFIG, self._base | MODE_CONTINUOUS | mux)

    def ready_os(self):
        """True when the chip is not converting (OS bit of the config register)."""
        return (self._read(REG_CONFIG) & OS) != 0

    def ready(self):
        """True when the conversion is done: the ALERT/RDY pin if there is one, else the OS bit."""
        if self.rdy is not None:
            return self.rdy.value() != 0
        return self.ready_os()

    def wait_ready(self, timeout_us, by_os=False):
        """Poll ready() (ready_os() when `by_os`) for up to `timeout_us`; False on a timeout.
        Never hangs: a chip that does not finish is the caller's sensor fault."""
        t0 = time.ticks_us()
        while True:
            if (self.ready_os() if by_os or self.rdy is None else self.rdy.value() != 0):
                return True
            if time.ticks_diff(time.ticks_us(), t0) >= timeout_us:
                return False

    def read_code(self):
        """The conversion register as a signed code (two's complement): -32768..32767."""
        v = self._read(REG_CONVERSION)
        return v - 0x10000 if v & 0x8000 else v

    def read(self, mux, timeout_us=None):
        """One single-shot conversion of `mux`: start, wait, read. OSError(ETIMEDOUT) when
        it does not finish within `timeout_us` after the conversion time (default: one
        more conversion time). For the REPL and the bench, not the sample loop."""
        self.start(mux)
        time.sleep_us(self.conversion_us)
        if not self.wait_ready(self.conversion_us if timeout_us is None else timeout_us):
            raise OSError(_ETIMEDOUT)
        return self.read_code()
