"""Frame packing against the shared test vectors (tests/vectors/frames.json), CRC-32 and COBS.

Runs under CPython and the real MicroPython: the node's own packer must give
the vectors' raw and wire bytes exactly, and its CRC-32 (ropenode.crc32, the
reference on the node) must equal binascii.crc32 where the port has it
(CPython always; the unix and wasm MicroPython builds here do, not every board).
"""
import struct

from firmware_rig import cobs_decode, frame_raw, load_json, unhex

from ropenode import layout
from ropenode.cobs import encode_into
from ropenode.crc32 import crc32_into
from ropenode.frame import FrameWriter, Hmac

try:
    from binascii import crc32 as lib_crc32
except ImportError:  # a port without it: the check values below still hold
    lib_crc32 = None


def crc32_of(data):
    """ropenode.crc32 of data, as an int (a test aid: the node never forms the 32-bit value)."""
    buf = bytearray(data) + bytearray(4)
    crc32_into(buf, len(data))
    return buf[-4] | (buf[-3] << 8) | (buf[-2] << 16) | (buf[-1] << 24)


class Rand:
    """xorshift32, the same bytes on every port."""

    def __init__(self, seed):
        self.s = seed

    def byte(self):
        s = self.s
        s ^= (s << 13) & 0xFFFFFFFF
        s ^= s >> 17
        s ^= (s << 5) & 0xFFFFFFFF
        self.s = s
        return s & 0xFF


def _vectors(version):
    """The good vectors of layout `version`: "good" holds version 3 (what the node sends),
    "good_v2" version 2 (what an older node sends)."""
    vec = load_json("tests/vectors/frames.json")
    assert vec["layout_version"] == layout.VERSION
    out = [v for v in vec["good"] + vec.get("good_v2", []) if v["fields"]["version"] == version]
    assert [v["fields"]["version"] for v in vec["good"]] == [layout.VERSION] * len(vec["good"])
    return out


def test_vectors_hold_both_versions_the_host_decodes():
    v3 = _vectors(3)
    v2 = _vectors(2)
    assert layout.VERSION == 3 and layout.VERSIONS == (2, 3)
    assert len(v3) >= 3 and len(v2) >= 1
    pos = [r[4] for v in v3 for r in v["fields"]["ropes"]]
    assert layout.POS_ABSENT in pos and len(set(pos)) > 2  # absent and present positions
    masks = [v["fields"]["stroke_mask"] for v in v3]
    assert 0 in masks and any(m & 0x0F for m in masks) and any(m & 0xF0 for m in masks)


def test_good_vectors_pack_exactly():
    vectors = _vectors(layout.VERSION)
    assert len(vectors) >= 3
    for v in vectors:
        f = v["fields"]
        w = FrameWriter(f["node"], unhex(v["key_hex"]))
        n = w.pack(f["kind"], f["fault_mask"], (f["seq"] & 0xFFFF, f["seq"] >> 16),
                   (f["time_ms"] & 0xFFFF, f["time_ms"] >> 16), f["status"],
                   f["ropes"] or None, f["depth_mm"], f["speed_mm_s"], f["battery_mv"],
                   f["oil_temp_cc"], f["stroke_mask"])
        wire = bytearray(layout.MAX_WIRE_LEN)
        m = w.seal_into(n, wire)
        raw = unhex(v["raw_hex"])
        assert bytes(w.raw[:len(raw)]) == raw, v["name"]
        assert bytes(wire[:m]) == unhex(v["wire_hex"]), v["name"]
        assert m <= layout.MAX_WIRE_LEN
        assert crc32_of(raw[:-4]) == struct.unpack("<I", raw[-4:])[0], v["name"]
        if lib_crc32 is not None:
            assert lib_crc32(raw[:-4]) == struct.unpack("<I", raw[-4:])[0], v["name"]


def test_version_2_vectors_follow_the_v2_layout():
    """The node sends no version 2 frame; the host's (an older node's) are the V2_* layout:
    lengths, fields, MAC and CRC-32 as layout.py says."""
    vectors = _vectors(2)
    assert vectors
    for v in vectors:
        f = v["fields"]
        raw = unhex(v["raw_hex"])
        n = len(f["ropes"])
        assert len(raw) == layout.frame_len(n, 2) and layout.ropes_in(len(raw), 2) == n, v["name"]
        assert layout.ropes_in(len(raw), 3) != n, v["name"]
        assert raw[0] == 2 and raw[3] == f["fault_mask"] and raw[2] == f["node"]
        o = layout.HEADER_LEN
        for r in f["ropes"]:
            assert struct.unpack_from(layout.V2_ROPE_FMT, raw, o) == tuple(r[:4]), v["name"]
            o += layout.V2_ROPE_LEN
        assert struct.unpack_from(layout.V2_TAIL_FMT, raw, o) == (
            f["depth_mm"], f["speed_mm_s"], f["battery_mv"], f["oil_temp_cc"]), v["name"]
        o += layout.V2_TAIL_LEN
        assert raw[o:o + layout.MAC_LEN] == Hmac(unhex(v["key_hex"])).digest(raw[:o])[:layout.MAC_LEN]
        assert crc32_of(raw[:-4]) == struct.unpack("<I", raw[-4:])[0], v["name"]
        wire = unhex(v["wire_hex"])
        assert frame_raw(wire, len(wire)) == raw, v["name"]


def test_crc32_check_value():
    assert crc32_of(b"123456789") == 0xCBF43926  # CRC-32/ISO-HDLC's catalogue check value
    assert crc32_of(b"") == 0


def test_crc32_equals_binascii_crc32():
    """Random lengths 0..300 and contents, all-0x00 and all-0xFF runs: the hand-written
    halves give binascii.crc32 exactly (where the port has it; always under CPython)."""
    if lib_crc32 is None:
        return
    rnd = Rand(2463534242)
    cases = [bytes(64), b"\xff" * 64, bytes(range(256))]
    for n in range(0, 301, 7):
        cases.append(bytes(rnd.byte() for _ in range(n)))
    for data in cases:
        assert crc32_of(data) == lib_crc32(data), len(data)


def test_crc32_writes_only_its_four_bytes():
    buf = bytearray(b"\xaa" * 20)
    assert crc32_into(buf, 9) == 13
    assert buf[13:] == b"\xaa" * 7 and buf[:9] == b"\xaa" * 9


def test_node_header_packs_the_same_bytes_as_the_wire_header():
    assert struct.calcsize(layout.NODE_HEADER_FMT) == struct.calcsize(layout.HEADER_FMT) == layout.HEADER_LEN
    for seq, t in ((0, 0), (1, 1000), (0x12345678, 0x9ABCDEF0), (0xFFFFFFFF, 0xFFFFFFFF)):
        wire = struct.pack(layout.HEADER_FMT, 1, 0, 7, 3, seq, t, 0x8001)
        node = struct.pack(layout.NODE_HEADER_FMT, 1, 0, 7, 3, seq & 0xFFFF, seq >> 16, t & 0xFFFF, t >> 16, 0x8001)
        assert node == wire


def test_hmac_matches_rfc4231_case_2():
    h = Hmac(b"Jefe").digest(b"what do ya want for nothing?")
    assert h == unhex("5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843")


def test_hmac_long_key_rfc4231_case_6():
    h = Hmac(b"\xaa" * 131).digest(b"Test Using Larger Than Block-Size Key - Hash Key First")
    assert h == unhex("60e431591ee0b67f0d8a26aacbf5b77f8e0bc6213728c5140546040f0ee37f54")


def test_cobs_round_trip_and_crc_trailer():
    w = FrameWriter(7, bytes(range(16)))
    ropes = [(0, -1, 32767, 0, 0), (-32768, 0, 0, 65535, -32768), (1, 256, 0, 0, 32767), (0, 0, 0, 0, -1)]
    n = w.pack(layout.KIND_DATA, 0, (0, 0), (0, 0), 0, ropes, 0, 0, 0, 0, 0x81)
    wire = bytearray(layout.MAX_WIRE_LEN)
    m = w.seal_into(n, wire)
    assert m == layout.MAX_WIRE_LEN == 76 and wire[0] == 0 and wire[m - 1] == 0  # 0x00 before and after
    assert all(b != 0 for b in wire[1:m - 1])
    raw = frame_raw(wire, m)  # checks the CRC-32 too
    assert len(raw) == layout.frame_len(4) == 73 and layout.ropes_in(73) == 4
    assert raw[0] == 3 and raw[n - 1] == 0x81  # the version, and the stroke mask last in the tail
    o = layout.HEADER_LEN
    for r in ropes:
        assert struct.unpack_from(layout.ROPE_FMT, raw, o) == r
        o += layout.ROPE_LEN
    assert raw[:len(raw) - layout.MAC_LEN - layout.CRC_LEN] == bytes(w.raw[:n])


def test_cobs_long_run_without_zeros():
    src = bytes(range(1, 256)) * 2
    dst = bytearray(len(src) + len(src) // 254 + 2)
    m = encode_into(src, len(src), dst)
    assert dst[m - 1] == 0 and cobs_decode(bytes(dst[:m - 1])) == src
