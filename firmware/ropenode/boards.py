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
