"""The radio frame layout: the one definition shared by the node and the host.

docs/protocol.md is the prose spec of what this module defines. Both the node
(`ropenode.frame`) and the host (`ropemon.station.protocol`) build their packers from
these constants, so the two cannot drift. Little-endian throughout.

    header  <BBBBIIH   version, kind, node, fault_mask, seq, time_ms, status
    rope    <hhhH      mean_dan, min_dan, max_dan, raw_kpa      (once per rope)
    tail    <ihHh      depth_mm, speed_mm_s, battery_mv, oil_temp_cc
    mac     4 bytes    HMAC-SHA256(key, everything before), truncated
    crc     <I         CRC-32 (IEEE 802.3, as binascii.crc32) over everything before

then COBS-encoded, with one 0x00 byte before and one after it on the wire.
"""
from micropython import const

VERSION = const(2)  # 1: CRC-16, no leading delimiter (refused by the host)

KIND_DATA = const(0)     # rope payload present (N ropes)
KIND_STATUS = const(1)   # no rope payload: the node cannot compensate (e.g. config fault)

HEADER_FMT = "<BBBBIIH"
HEADER_FIELDS = ("version", "kind", "node", "fault_mask", "seq", "time_ms", "status")
HEADER_LEN = const(14)
# The node packs the same 14 bytes with seq and time_ms as 16-bit halves, low first:
# no int it handles then reaches 2**30 (a small int on a 32-bit MicroPython)
NODE_HEADER_FMT = "<BBBBHHHHH"

ROPE_FMT = "<hhhH"
ROPE_FIELDS = ("mean_dan", "min_dan", "max_dan", "raw_kpa")
ROPE_LEN = const(8)

TAIL_FMT = "<ihHh"
TAIL_FIELDS = ("depth_mm", "speed_mm_s", "battery_mv", "oil_temp_cc")
TAIL_LEN = const(10)

MAC_LEN = const(4)
CRC_LEN = const(4)

# Bytes of a frame before COBS, for n ropes.
FIXED_LEN = const(32)  # HEADER_LEN + TAIL_LEN + MAC_LEN + CRC_LEN

MAX_ROPES = const(4)   # 4 ropes -> 64 bytes raw -> at most 67 bytes on the wire
# 0x00 + COBS(64 raw bytes: 65) + 0x00. 10 frames/s x 67 bytes x 10 bits = 6700 bit/s,
# inside 70 % of a 9600-baud link (docs/protocol.md, "Bandwidth").
MAX_WIRE_LEN = const(67)

# Status bits (header field `status`).
ST_PRESSURE_FAULT = const(0x0001)     # a pressure loop is outside NAMUR NE43 (see fault_mask)
ST_DISPLACEMENT_FAULT = const(0x0002) # a displacement channel is out of range (see fault_mask)
ST_CONFIG_FAULT = const(0x0004)       # config missing or invalid: no compensation
ST_BATTERY_LOW = const(0x0008)
ST_WATCHDOG_RESET = const(0x0010)     # the last reset was by the watchdog
ST_IMBALANCE = const(0x0020)          # a rope's window mean deviates beyond the node threshold
ST_SPEED_FAULT = const(0x0040)        # counter glitch (jump beyond max pulses/sample), or a Hall mark with no speed pulses
ST_TEMP_ABSENT = const(0x0080)        # no oil temperature input: assumed temperature used
ST_OVERRUN = const(0x0100)            # samples were missed (processing slower than the timer)
ST_NOISE_CHANGED = const(0x0200)      # the pressure channels' noise moved beyond NOISE_TOL_Q10 of the commissioned
# noise following (docs/model.md): the node flags a ratio of its measured pressure noise to
# the commissioned one beyond 1 +- this/1024 (the host's fit-compliance re-check tolerance)
NOISE_TOL_Q10 = const(256)

STATUS_BITS = (
    ("pressure_fault", ST_PRESSURE_FAULT),
    ("displacement_fault", ST_DISPLACEMENT_FAULT),
    ("config_fault", ST_CONFIG_FAULT),
    ("battery_low", ST_BATTERY_LOW),
    ("watchdog_reset", ST_WATCHDOG_RESET),
    ("imbalance", ST_IMBALANCE),
    ("speed_fault", ST_SPEED_FAULT),
    ("temp_absent", ST_TEMP_ABSENT),
    ("overrun", ST_OVERRUN),
    ("noise_changed", ST_NOISE_CHANGED),
)

OIL_TEMP_ABSENT = const(-32768)  # oil_temp_cc value when no temperature input is fitted


def frame_len(n_ropes):
    """Bytes of a frame before COBS for n_ropes rope records."""
    return FIXED_LEN + ROPE_LEN * n_ropes


def ropes_in(length):
    """Rope count of a raw frame of `length` bytes, or -1 if no count fits."""
    body = length - FIXED_LEN
    if body < 0 or body % ROPE_LEN:
        return -1
    return body // ROPE_LEN

# A rope with no healthy sample in the frame window (its loop failed, see
# fault_mask) carries these instead of values: never a made-up tension.
TENSION_ABSENT = const(-32768)   # mean_dan, min_dan, max_dan
RAW_KPA_ABSENT = const(0xFFFF)   # raw_kpa

# fault_mask (header): bit i = pressure loop of rope i outside NAMUR NE43,
# bit 4+i = displacement channel of rope i out of range.
FAULT_PRESSURE_SHIFT = const(0)
FAULT_DISPLACEMENT_SHIFT = const(4)
