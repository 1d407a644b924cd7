"""Board tables: every pin, bus and front-end figure of a cage node board, one dict per board.

Another board is a new table here, not a new HAL. `BOARD` names the one the
node runs (hal_board.run(board=...) takes another). The reference board and
its wiring: docs/hardware.md.

Keys of a table:
    i2c          (id, SCL pin, SDA pin, Hz) of the ADS1115s' bus
    ads          I2C addresses of the ADS1115s; "chip" below is an index into it
    fs_mv, sps   ADS1115 full-scale range (PGA) and data rate of every conversion
    rdy          pin of the ALERT/RDY lines (all chips', wired together, pull-up), or None:
                 conversion ready is then polled by the OS bit over I2C
    shunt_ohm    each 4-20 mA loop's shunt to ground (0.1 %)
    pressure     (chip, AIN) of each rope's pressure loop, rope order
    displacement (chip, AIN) of each rope's displacement loop
    battery      (chip, AIN) of the battery divider; battery_div: its ratio (2 = half the cell)
    temperature  (chip, AIN) of the oil temperature loop (read only when node.json says fitted)
    encoder      (machine.Counter id, pulse pin, direction pin)
    hall         (sensor A pin, sensor B pin), low over a mark, internal pull-ups
    radio        (UART id, TX pin, RX pin, baud), 8N1
    port         the MicroPython port the board runs ("esp32", "rp2", "stm32"): what its
                 machine.WDT accepts (WDT_MAX_MS)
    wdt_maintenance_ms  the watchdog's timeout once the loop is interrupted (Ctrl-C at the
                 REPL, mpremote): the maintenance window (hal_board.maintenance); from
                 WDT_MS to the port's WDT_MAX_MS

The stream word of a loop is the ADS1115 code times 2 (WORD_SHIFT), so that
the 16-bit .rsens words span the ADC's positive range: on the reference board
(+-4.096 V, 150 ohm) 4 mA = 0.6 V = code 4800 = word 9600, 20 mA = word 48000.
`loop_ua` turns a word back into the loop current; `loop_state` applies
NAMUR NE43 to a word, as the host's commissioning does (ropemon.commission.nodejson.namur_limits).
"""
from micropython import const

from ropenode.ads1115 import code_uv

WORD_SHIFT = const(1)       # stream word = ADS1115 code << 1 (0..32767 -> 0..65534)
NAMUR_LO_UA = const(3600)   # NE43: below 3.6 mA a failed signal (open loop, dead transmitter)
NAMUR_HI_UA = const(21000)  # NE43: above 21 mA a failed signal (short, transmitter fault)
LOOP_OK = const(0)
LOOP_LOW = const(1)
LOOP_HIGH = const(2)

# The watchdog: WDT_MS while the loop samples (ropenode.hal_board), the board's
# wdt_maintenance_ms once it is interrupted. WDT_MAX_MS: the longest timeout each port's
# machine.WDT accepts again once it runs (its machine_wdt.c): rp2 refuses more than 8388 ms
# (RP2040), stm32's IWDG more than 32767 ms; esp32 reconfigures its task watchdog to any
# timeout, capped here at 1 h.
WDT_MS = const(2000)
WDT_MAX_MS = {"esp32": 3_600_000, "rp2": 8388, "stm32": 32767}

BOARDS = {
    # The reference board (docs/hardware.md): ESP32-DevKitC V4 (ESP32-WROOM-32E) on a
    # carrier with four ADS1115 modules. Not yet run on hardware: bring it up on the bench
    # (docs/hardware.md) before it goes on a cage.
    "esp32-devkitc": {
        "i2c": (0, 22, 21, 400_000),
        "ads": (0x48, 0x49, 0x4A, 0x4B),
        "fs_mv": 4096,
        "sps": 860,
        "rdy": 27,
        "shunt_ohm": 150,
        "pressure": ((0, 0), (1, 0), (2, 0), (3, 0)),
        "displacement": ((0, 1), (1, 1), (2, 1), (3, 1)),
        "battery": (0, 2),
        "battery_div": 2,
        "temperature": (1, 2),
        "encoder": (0, 25, 26),
        "hall": (32, 33),
        "radio": (1, 17, 16, 9600),
        "port": "esp32",
        "wdt_maintenance_ms": 1_200_000,  # 20 min: longer than any ropemon step (record --fetch: 920 s)
    },
    # The same front end on an ESP32-S3-DevKitC-1 (pins of the S3; GPIO 19/20 are its
    # USB, 0/3/45/46 strapping, 26..37 flash and PSRAM). A table only: never built.
    "esp32s3-devkitc": {
        "i2c": (0, 9, 8, 400_000),
        "ads": (0x48, 0x49, 0x4A, 0x4B),
        "fs_mv": 4096,
        "sps": 860,
        "rdy": 10,
        "shunt_ohm": 150,
        "pressure": ((0, 0), (1, 0), (2, 0), (3, 0)),
        "displacement": ((0, 1), (1, 1), (2, 1), (3, 1)),
        "battery": (0, 2),
        "battery_div": 2,
        "temperature": (1, 2),
        "encoder": (0, 4, 5),
        "hall": (6, 7),
        "radio": (1, 17, 18, 9600),
        "port": "esp32",
        "wdt_maintenance_ms": 1_200_000,  # 20 min: longer than any ropemon step (record --fetch: 920 s)
    },
}

BOARD = "esp32-devkitc"


def get(name=None):
    """The table of board `name` (default BOARD); ValueError names the known boards."""
    name = BOARD if name is None else name
    t = BOARDS.get(name)
    if t is None:
        raise ValueError("board %r: not one of %s" % (name, ", ".join(sorted(BOARDS))))
    return t


def maintenance_ms(t):
    """The maintenance timeout in ms of board table `t`: its wdt_maintenance_ms clamped to
    WDT_MS .. its port's WDT_MAX_MS (WDT_MS for an unknown port). Never raises: a wrong
    table must not keep a node from sampling (check() is the test's refusal)."""
    top = WDT_MAX_MS.get(t.get("port"), WDT_MS)
    ms = t.get("wdt_maintenance_ms", WDT_MS)
    return WDT_MS if ms < WDT_MS else top if ms > top else ms


def check(t):
    """ValueError unless table `t` names a known port and its wdt_maintenance_ms is an int
    within WDT_MS .. that port's WDT_MAX_MS."""
    port = t.get("port")
    if port not in WDT_MAX_MS:
        raise ValueError("port %r: not one of %s" % (port, ", ".join(sorted(WDT_MAX_MS))))
    ms = t.get("wdt_maintenance_ms")
    if type(ms) is not int or not WDT_MS <= ms <= WDT_MAX_MS[port]:
        raise ValueError("wdt_maintenance_ms %r: %s needs %d .. %d" % (ms, port, WDT_MS, WDT_MAX_MS[port]))


def loop_uv(word, fs_mv):
    """Shunt voltage in uV of a stream word (word >> 1 is the ADS1115 code)."""
    return code_uv(word >> WORD_SHIFT, fs_mv)


def loop_ua(word, fs_mv, shunt_ohm):
    """Loop current in uA of a stream word, floored: (word >> 1) codes x FS / 32768 / shunt."""
    return loop_uv(word, fs_mv) // shunt_ohm


def loop_state(word, fs_mv, shunt_ohm):
    """NAMUR NE43 for a stream word: LOOP_OK for 3.6..21 mA (limits included), LOOP_LOW
    below (open loop, dead transmitter), LOOP_HIGH above. Compared in uV, not in floored uA,
    so that it agrees word for word with the node's fault limits from `ropemon config`."""
    uv = loop_uv(word, fs_mv)
    if uv < NAMUR_LO_UA * shunt_ohm:
        return LOOP_LOW
    if uv > NAMUR_HI_UA * shunt_ohm:
        return LOOP_HIGH
    return LOOP_OK
