"""The radio frame layout: the one definition shared by the node and the host.

docs/protocol.md is the prose spec of what this module defines. Both the node
(`ropenode.frame`) and the host (`ropemon.station.protocol`) build their packers from
these constants, so the two cannot drift. Little-endian throughout.

    header  <BBBBIIH   version, kind, node, fault_mask, seq, time_ms, status
    rope    <hhhHh     mean_dan, min_dan, max_dan, raw_kpa, pos_01mm   (once per rope)
    tail    <ihHhB     depth_mm, speed_mm_s, battery_mv, oil_temp_cc, stroke_mask
    mac     4 bytes    HMAC-SHA256(key, everything before), truncated
    crc     <I         CRC-32 (IEEE 802.3, as binascii.crc32) over everything before

then COBS-encoded, with one 0x00 byte before and one after it on the wire.
"""
from micropython import const

VERSION = const(3)  # what the node sends; 1: CRC-16, no leading delimiter (refused by the host)
# Versions the host decodes side by side (a mine upgrades its nodes one cage at a time).
# Version 2 is version 3 without pos_01mm and stroke_mask: V2_* below.
VERSIONS = (2, 3)

KIND_DATA = const(0)     # rope payload present (N ropes)
KIND_STATUS = const(1)   # no rope payload: the node cannot compensate (e.g. config fault)

HEADER_FMT = "<BBBBIIH"
HEADER_FIELDS = ("version", "kind", "node", "fault_mask", "seq", "time_ms", "status")
HEADER_LEN = const(14)
# The node packs the same 14 bytes with seq and time_ms as 16-bit halves, low first:
# no int it handles then reaches 2**30 (a small int on a 32-bit MicroPython)
NODE_HEADER_FMT = "<BBBBHHHHH"

ROPE_FMT = "<hhhHh"
ROPE_FIELDS = ("mean_dan", "min_dan", "max_dan", "raw_kpa", "pos_01mm")
ROPE_LEN = const(10)

TAIL_FMT = "<ihHhB"
TAIL_FIELDS = ("depth_mm", "speed_mm_s", "battery_mv", "oil_temp_cc", "stroke_mask")
TAIL_LEN = const(11)

V2_ROPE_FMT = "<hhhH"
V2_ROPE_FIELDS = ("mean_dan", "min_dan", "max_dan", "raw_kpa")
V2_ROPE_LEN = const(8)
V2_TAIL_FMT = "<ihHh"
V2_TAIL_FIELDS = ("depth_mm", "speed_mm_s", "battery_mv", "oil_temp_cc")
V2_TAIL_LEN = const(10)
V2_FIXED_LEN = const(32)

MAC_LEN = const(4)
CRC_LEN = const(4)

# Bytes of a frame before COBS, for n ropes.
FIXED_LEN = const(33)  # HEADER_LEN + TAIL_LEN + MAC_LEN + CRC_LEN

MAX_ROPES = const(4)   # 4 ropes -> 73 bytes raw -> at most 76 bytes on the wire
# 0x00 + COBS(73 raw bytes: 74) + 0x00. 10 frames/s x 76 bytes x 10 bits = 7600 bit/s
# (docs/protocol.md, "Bandwidth").
MAX_WIRE_LEN = const(76)

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
ST_STROKE_LIMIT = const(0x0400)       # a piston came within the stroke margin of an end (see stroke_mask)
# bits 11-14: rope i's compensation held back at rest in the window (do no harm, docs/model.md)
ST_HELD_BACK_SHIFT = const(11)
ST_HELD_BACK_MASK = const(0x7800)
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
    ("stroke_limit", ST_STROKE_LIMIT),
    ("held_back", ST_HELD_BACK_MASK),
)

OIL_TEMP_ABSENT = const(-32768)  # oil_temp_cc value when no temperature input is fitted


def frame_len(n_ropes, version=VERSION):
    """Bytes of a frame of layout `version` (2 or 3) before COBS for n_ropes rope records."""
    if version == 2:
        return V2_FIXED_LEN + V2_ROPE_LEN * n_ropes
    return FIXED_LEN + ROPE_LEN * n_ropes


def ropes_in(length, version=VERSION):
    """Rope count of a raw frame of layout `version` of `length` bytes, or -1 if no count fits."""
    if version == 2:
        fixed, rope = V2_FIXED_LEN, V2_ROPE_LEN
    else:
        fixed, rope = FIXED_LEN, ROPE_LEN
    body = length - fixed
    if body < 0 or body % rope:
        return -1
    return body // rope

# A rope with no healthy sample in the frame window (its loop failed, see
# fault_mask) carries these instead of values: never a made-up tension.
TENSION_ABSENT = const(-32768)   # mean_dan, min_dan, max_dan
RAW_KPA_ABSENT = const(0xFFFF)   # raw_kpa
# pos_01mm (version 3): the piston position's window mean in 0.1 mm from mid-stroke, x > 0 pulled
# out by the rope (docs/model.md), over the samples its displacement channel was healthy; this
# when it had none
POS_ABSENT = const(-32768)

# stroke_mask (version 3, tail): bit i = rope i's piston within the stroke margin of its
# retracted end (x low) at any sample of the window, bit 4+i = of its extended end (x high).
STROKE_LOW_SHIFT = const(0)
STROKE_HIGH_SHIFT = const(4)

# fault_mask (header): bit i = pressure loop of rope i outside NAMUR NE43,
# bit 4+i = displacement channel of rope i out of range.
FAULT_PRESSURE_SHIFT = const(0)
FAULT_DISPLACEMENT_SHIFT = const(4)
