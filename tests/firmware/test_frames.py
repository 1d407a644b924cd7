"""Frame packing against the shared test vectors (tests/vectors/frames.json), CRC and COBS.

Runs under CPython and the real MicroPython: the node's own packer must give
the vectors' raw and wire bytes exactly.
"""
import struct

from fwtest_util import cobs_decode, load_json, unhex

from ropenode import layout
from ropenode.cobs import encode_into
from ropenode.crc16 import crc16
from ropenode.frame import FrameWriter, Hmac


def test_good_vectors_pack_exactly():
    vec = load_json("tests/vectors/frames.json")
    assert vec["layout_version"] == layout.VERSION
    assert len(vec["good"]) >= 3
    for v in vec["good"]:
        f = v["fields"]
        w = FrameWriter(f["node"], unhex(v["key_hex"]))
        n = w.pack(f["kind"], f["fault_mask"], (f["seq"] & 0xFFFF, f["seq"] >> 16),
                   (f["time_ms"] & 0xFFFF, f["time_ms"] >> 16), f["status"],
                   f["ropes"] or None, f["depth_mm"], f["speed_mm_s"], f["battery_mv"],
                   f["oil_temp_cc"])
        wire = bytearray(64)
        m = w.seal_into(n, wire)
        raw = unhex(v["raw_hex"])
        assert bytes(w.raw[:len(raw)]) == raw, v["name"]
        assert bytes(wire[:m]) == unhex(v["wire_hex"]), v["name"]
        assert m <= layout.MAX_WIRE_LEN


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
    ropes = [(0, -1, 32767, 0), (-32768, 0, 0, 65535), (1, 256, 0, 0), (0, 0, 0, 0)]
    n = w.pack(layout.KIND_DATA, 0, (0, 0), (0, 0), 0, ropes, 0, 0, 0, 0)
    wire = bytearray(64)
    m = w.seal_into(n, wire)
    assert m == layout.MAX_WIRE_LEN and wire[m - 1] == 0
    assert all(b != 0 for b in wire[:m - 1])
    raw = cobs_decode(bytes(wire[:m - 1]))
    assert len(raw) == layout.frame_len(4)
    assert crc16(raw, len(raw) - 2) == raw[-2] | (raw[-1] << 8)
    assert raw[:len(raw) - 6] == bytes(w.raw[:n])


def test_cobs_long_run_without_zeros():
    src = bytes(range(1, 256)) * 2
    dst = bytearray(len(src) + len(src) // 254 + 2)
    m = encode_into(src, len(src), dst)
    assert dst[m - 1] == 0 and cobs_decode(bytes(dst[:m - 1])) == src
