"""Write tests/vectors/frames.json: frame test vectors for the node encoder and the host decoder.

Each good vector (`good`: layout version 3, what the node sends; `good_v2`: frames of
a version 2 node, which the host still decodes): the fields and key, the raw frame
(before COBS) and the wire bytes (0x00 + COBS + 0x00), both hex. Each bad vector: wire
bytes and the decoder count it must land in. Deterministic; tests/host/test_host_vectors.py checks that the
file equals what this script writes, and that the host decodes every vector.

    .venv/bin/python tools/make_frame_vectors.py
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "host"))

from ropemon.station.protocol import L, encode_frame  # noqa: E402

OUT = ROOT / "tests" / "vectors" / "frames.json"
KEY_1 = bytes(range(1, 17))                       # 16-byte key of node 1
KEY_7 = bytes.fromhex("a5" * 32)                  # 32-byte key of node 7


A = L.POS_ABSENT
LOW, HIGH = L.STROKE_LOW_SHIFT, L.STROKE_HIGH_SHIFT

# Version 3: every rope record ends in pos_01mm (0.1 mm from mid-stroke, x > 0 pulled out;
# POS_ABSENT: no healthy displacement sample), the tail in stroke_mask.
CASES = [
    ("four_ropes_at_rest", KEY_1, dict(node=1, seq=1, time_ms=1000, ropes=[
        (4630, 4610, 4650, 6170, 12), (4615, 4600, 4630, 6150, -35), (4640, 4625, 4660, 6185, 0),
        (4620, 4605, 4640, 6160, 101)],
        depth_mm=0, speed_mm_s=0, battery_mv=7400, oil_temp_cc=1850)),
    ("four_ropes_moving_down_deep", KEY_1, dict(node=1, seq=123456, time_ms=4_000_000_000, ropes=[
        (5210, 5100, 5330, 5890, -1503), (5190, 5050, 5300, 5860, -1498), (5230, 5120, 5350, 5900, -1510),
        (5205, 5090, 5310, 5880, -1495)],
        depth_mm=805_250, speed_mm_s=10_000, battery_mv=7100, oil_temp_cc=-250)),
    ("moving_up_negative_speed", KEY_7, dict(node=7, seq=2**32 - 1, time_ms=2**32 - 1, ropes=[
        (3000, 2900, 3100, 4000, 250), (3000, 2900, 3100, 4000, -250)],
        depth_mm=-1200, speed_mm_s=-10_000, battery_mv=6500, oil_temp_cc=L.OIL_TEMP_ABSENT,
        status=L.ST_TEMP_ABSENT)),
    ("extremes_of_every_field", KEY_7, dict(node=255, seq=0, time_ms=0, ropes=[
        (-32768, -32768, 32767, 65535, 32767)], fault_mask=255, status=0xFFFF,
        depth_mm=-2**31, speed_mm_s=32767, battery_mv=65535, oil_temp_cc=32767, stroke_mask=0xFF)),
    ("zero_bytes_everywhere", KEY_1, dict(node=0, seq=0, time_ms=0, ropes=[(0, 0, 0, 0, 0)] * 4)),
    ("config_fault_status_frame", KEY_1, dict(node=1, seq=2, time_ms=1100, ropes=[],
        status=L.ST_CONFIG_FAULT | L.ST_BATTERY_LOW, battery_mv=6000, depth_mm=0)),
    ("pressure_fault_rope_2", KEY_1, dict(node=1, seq=3, time_ms=1200, ropes=[
        (4630, 4610, 4650, 6170, 10), (4615, 4600, 4630, 6150, 12), (0, 0, 0, 0, 11), (4620, 4605, 4640, 6160, 9)],
        fault_mask=0b0100, status=L.ST_PRESSURE_FAULT, battery_mv=7400, oil_temp_cc=1850)),
    ("rope_2_absent_whole_window", KEY_1, dict(node=1, seq=4, time_ms=1300, ropes=[
        (4630, 4610, 4650, 6170, 10), (4615, 4600, 4630, 6150, 12),
        (L.TENSION_ABSENT, L.TENSION_ABSENT, L.TENSION_ABSENT, L.RAW_KPA_ABSENT, 11), (4620, 4605, 4640, 6160, 9)],
        fault_mask=0b0100, status=L.ST_PRESSURE_FAULT, battery_mv=7400, oil_temp_cc=1850)),
    # rope 3's displacement channel failed the whole window: its position is absent, a
    # displacement fault (fault_mask bit 4+i), never a stroke bit
    ("rope_3_position_absent", KEY_1, dict(node=1, seq=5, time_ms=1400, ropes=[
        (4630, 4610, 4650, 6170, 10), (4615, 4600, 4630, 6150, 12), (4640, 4625, 4660, 6185, 11),
        (4620, 4605, 4640, 6160, A)],
        fault_mask=1 << (L.FAULT_DISPLACEMENT_SHIFT + 3), status=L.ST_DISPLACEMENT_FAULT, battery_mv=7400,
        oil_temp_cc=1850)),
    ("no_position_on_any_rope", KEY_7, dict(node=7, seq=6, time_ms=1500, ropes=[(3000, 2950, 3050, 3900, A)] * 3,
        fault_mask=0b0111 << L.FAULT_DISPLACEMENT_SHIFT, status=L.ST_DISPLACEMENT_FAULT, battery_mv=7000)),
    # rope 1 (index 0) near its retracted end, rope 4 (index 3) near its extended end
    ("stroke_limit_ropes_1_low_4_high", KEY_1, dict(node=1, seq=7, time_ms=1600, ropes=[
        (4000, 3900, 4100, 5200, -1420), (4700, 4650, 4750, 6250, -30), (4710, 4660, 4760, 6260, 15),
        (5400, 5350, 5450, 6900, 1433)],
        status=L.ST_STROKE_LIMIT, stroke_mask=(1 << (LOW + 0)) | (1 << (HIGH + 3)), battery_mv=7400,
        oil_temp_cc=1850)),
    ("stroke_limit_both_ends_in_one_window", KEY_7, dict(node=7, seq=8, time_ms=1700, ropes=[
        (3000, 2000, 4000, 4000, 0), (3000, 2900, 3100, 4000, 5)],
        status=L.ST_STROKE_LIMIT, stroke_mask=(1 << (LOW + 0)) | (1 << (HIGH + 0)), battery_mv=6500)),
]

# Version 2 (a node not yet upgraded): no pos_01mm, no stroke_mask.
CASES_V2 = [
    ("v2_four_ropes_at_rest", KEY_1, dict(node=1, seq=1, time_ms=1000, ropes=[
        (4630, 4610, 4650, 6170), (4615, 4600, 4630, 6150), (4640, 4625, 4660, 6185), (4620, 4605, 4640, 6160)],
        depth_mm=0, speed_mm_s=0, battery_mv=7400, oil_temp_cc=1850)),
    ("v2_moving_up_negative_speed", KEY_7, dict(node=7, seq=2**32 - 1, time_ms=2**32 - 1, ropes=[
        (3000, 2900, 3100, 4000), (3000, 2900, 3100, 4000)],
        depth_mm=-1200, speed_mm_s=-10_000, battery_mv=6500, oil_temp_cc=L.OIL_TEMP_ABSENT,
        status=L.ST_TEMP_ABSENT)),
    ("v2_config_fault_status_frame", KEY_1, dict(node=1, seq=2, time_ms=1100, ropes=[],
        status=L.ST_CONFIG_FAULT | L.ST_BATTERY_LOW, battery_mv=6000, depth_mm=0)),
]


def _vectors(cases: list, version: int) -> list[dict]:
    out = []
    for name, key, f in cases:
        raw, wire = encode_frame(key=key, version=version, **f)
        fields = {k: (list(map(list, v)) if k == "ropes" else v) for k, v in f.items()}
        fields.setdefault("status", 0)
        fields.setdefault("fault_mask", 0)
        for k in ("depth_mm", "speed_mm_s", "battery_mv"):
            fields.setdefault(k, 0)
        fields.setdefault("oil_temp_cc", L.OIL_TEMP_ABSENT)
        if version >= 3:
            fields.setdefault("stroke_mask", 0)
        fields["kind"] = L.KIND_DATA if f["ropes"] else L.KIND_STATUS
        fields["version"] = version
        out.append({"name": name, "key_hex": key.hex(), "fields": fields, "raw_hex": raw.hex(),
                    "wire_hex": wire.hex()})
    return out


def good_vectors() -> list[dict]:
    return _vectors(CASES, L.VERSION)


def good_v2_vectors() -> list[dict]:
    return _vectors(CASES_V2, 2)


def _wire(raw: bytes) -> str:
    from cobs import cobs
    return (b"\x00" + cobs.encode(raw) + b"\x00").hex()


def _recrc(raw: bytes | bytearray) -> bytes:
    from ropemon.station.protocol import crc32
    b = bytearray(raw)
    b[-4:] = crc32(bytes(b[:-4])).to_bytes(4, "little")
    return bytes(b)


def bad_vectors(good: list[dict], good_v2: list[dict]) -> list[dict]:
    import binascii

    from ropemon.station.protocol import crc32
    wire = bytes.fromhex(good[0]["wire_hex"])
    raw = bytes.fromhex(good[0]["raw_hex"])
    raw_v2 = bytes.fromhex(good_v2[0]["raw_hex"])
    flipped = bytearray(wire)
    flipped[20] ^= 0x04
    bad_mac = bytearray(raw)
    bad_mac[-5] ^= 0x01  # inside the MAC; CRC recomputed so only the MAC is wrong
    bad_mac[-4:] = crc32(bytes(bad_mac[:-4])).to_bytes(4, "little")
    v3 = bytearray(raw)
    v3[0] = L.VERSION + 1
    v3[-4:] = crc32(bytes(v3[:-4])).to_bytes(4, "little")
    # The same frame as a node of layout version 1 sent it: version 2's records,
    # CRC-16/CCITT-FALSE, 2 bytes shorter.
    v1 = bytearray(raw_v2[:-4])
    v1[0] = 1
    v1 += binascii.crc_hqx(bytes(v1), 0xFFFF).to_bytes(2, "little")
    return [
        {"name": "bit_flip", "wire_hex": bytes(flipped).hex(), "count": "crc_fail"},
        {"name": "truncated", "wire_hex": (wire[:40] + b"\x00").hex(), "count": "malformed"},
        {"name": "overlong_garbage", "wire_hex": (b"\x55" * 100 + b"\x00").hex(), "count": "malformed"},
        {"name": "mac_wrong", "wire_hex": _wire(bytes(bad_mac)), "count": "mac_fail"},
        {"name": "unknown_version", "wire_hex": _wire(bytes(v3)), "count": "malformed", "version": L.VERSION + 1},
        {"name": "version_1_frame", "wire_hex": _wire(bytes(v1)), "count": "malformed", "version": 1},
        # intact CRC-32, a known version byte, but the length of the other version's frame
        {"name": "version_2_byte_at_version_3_length", "wire_hex": _wire(_recrc(b"\x02" + raw[1:])),
         "count": "malformed"},
        {"name": "version_3_byte_at_version_2_length", "wire_hex": _wire(_recrc(b"\x03" + raw_v2[1:])),
         "count": "malformed"},
        # intact CRC-32, version 3, a length that is no rope count's (one rope byte short)
        {"name": "version_3_odd_length", "wire_hex": _wire(_recrc(raw[:L.HEADER_LEN + 9] + raw[L.HEADER_LEN + 10:])),
         "count": "malformed"},
        {"name": "junk_then_frame", "wire_hex": (b"\x13\x37" * 20).hex() + good[0]["wire_hex"],
         "count": "malformed", "then": good[0]["name"]},
    ]


def build() -> dict:
    good = good_vectors()
    good_v2 = good_v2_vectors()
    return {
        "about": "ropemon frame test vectors; generated by tools/make_frame_vectors.py; layout in "
                 "firmware/ropenode/layout.py. raw = frame before COBS, wire = 00 + COBS(raw) + 00. "
                 "Keys: key_hex is the node's HMAC-SHA256 key (MAC = first 4 bytes). "
                 "good: layout version 3 (what the node sends; ropes [mean_dan, min_dan, max_dan, raw_kpa, "
                 "pos_01mm], stroke_mask in the tail); good_v2: version 2 frames (no pos_01mm, no "
                 "stroke_mask), which the host decodes with pos_01mm POS_ABSENT and stroke_mask 0. "
                 "Bad vectors are decoded with every good vector's key configured; `version`: the "
                 "layout version the decoder names; `then`: the good vector decoded after the junk.",
        "layout_version": L.VERSION,
        "good": good,
        "good_v2": good_v2,
        "bad": bad_vectors(good, good_v2),
    }


def render() -> str:
    return json.dumps(build(), indent=1) + "\n"


if __name__ == "__main__":
    OUT.write_text(render())
    print(f"wrote {OUT}")
