"""Frame packing: layout.py fields -> truncated HMAC-SHA256 -> CRC-32 -> 0x00 + COBS + 0x00.

docs/protocol.md is the spec. The HMAC key blocks (key XOR ipad/opad) are
built once per key; each frame costs two SHA-256 runs over at most 64 + 65
bytes, and the CRC-32 over 69 (`ropenode.crc32`: 16-bit halves, allocation-free).
Called once per frame window, never per sample.
"""
import hashlib
import struct

from ropenode import layout
from ropenode.cobs import encode_into
from ropenode.crc32 import crc32_into


class Hmac:
    """HMAC-SHA256 (RFC 2104) with the padded key blocks precomputed."""

    def __init__(self, key):
        key = bytes(key)
        if len(key) > 64:
            key = hashlib.sha256(key).digest()
        k = bytearray(64)
        k[:len(key)] = key
        self.ipad = bytes(b ^ 0x36 for b in k)
        self.opad = bytes(b ^ 0x5C for b in k)

    def digest(self, data):
        h = hashlib.sha256(self.ipad)
        h.update(data)
        inner = h.digest()
        h = hashlib.sha256(self.opad)
        h.update(inner)
        return h.digest()


class FrameWriter:
    """Packs frames of one node into a preallocated raw buffer, then onto the wire."""

    def __init__(self, node_id, key):
        self.node_id = node_id
        self.hmac = Hmac(key)
        self.raw = bytearray(layout.frame_len(layout.MAX_ROPES))
        self.raw_mv = memoryview(self.raw)

    def pack(self, kind, fault_mask, seq, time_ms, status, ropes, depth_mm, speed_mm_s,
             battery_mv, oil_temp_cc, stroke_mask=0):
        """Fill header, rope records (`ropes` is a list of (mean, min, max, raw_kpa,
        pos_01mm) or None for none) and tail; return the length before MAC and CRC.
        Layout `layout.VERSION` (3) only: the node sends no other.

        `seq` and `time_ms` are (low, high) 16-bit halves of the u32 fields."""
        raw = self.raw
        struct.pack_into(layout.NODE_HEADER_FMT, raw, 0, layout.VERSION, kind, self.node_id,
                         fault_mask, seq[0], seq[1], time_ms[0], time_ms[1], status)
        o = layout.HEADER_LEN
        if ropes:
            for r in ropes:
                struct.pack_into(layout.ROPE_FMT, raw, o, r[0], r[1], r[2], r[3], r[4])
                o += layout.ROPE_LEN
        struct.pack_into(layout.TAIL_FMT, raw, o, depth_mm, speed_mm_s, battery_mv, oil_temp_cc,
                         stroke_mask)
        return o + layout.TAIL_LEN

    def seal_into(self, n, wire):
        """Append MAC and CRC to raw[:n], write 0x00 + COBS + 0x00 into wire (at least
        layout.MAX_WIRE_LEN bytes); return bytes on the wire.

        The leading 0x00 ends whatever the receiver heard before (noise, a cut
        frame), so this frame is not lost with it."""
        raw = self.raw
        mac = self.hmac.digest(self.raw_mv[:n])
        raw[n:n + layout.MAC_LEN] = mac[:layout.MAC_LEN]
        n = crc32_into(raw, n + layout.MAC_LEN)
        wire[0] = 0
        return encode_into(raw, n, wire, 1)
