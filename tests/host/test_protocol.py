"""Frame encoding/decoding, the test-vector file, and the decoder's counts per failure."""
from __future__ import annotations

import binascii
import hashlib
import hmac
import importlib.util
import json
from pathlib import Path

import pytest

from host_rig import KEYS, frame_set
from ropemon.station.decoder import ReplayGuard, StreamDecoder
from ropemon.firmware import node_module
from ropemon.station.protocol import (L, CRC_RESIDUE, CrcError, MacError, MalformedError, Rope, VersionError,
                                      crc32, decode_raw, decode_wire, encode_frame)

ROOT = Path(__file__).resolve().parents[2]
VECTORS = ROOT / "tests" / "vectors" / "frames.json"


def load_vectors() -> dict:
    return json.loads(VECTORS.read_text())


def test_vector_file_is_what_the_generator_writes():
    spec = importlib.util.spec_from_file_location("make_frame_vectors", ROOT / "tools" / "make_frame_vectors.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert VECTORS.read_text() == mod.render(), "run tools/make_frame_vectors.py"


@pytest.mark.parametrize("v", load_vectors()["good"], ids=lambda v: v["name"])
def test_good_vectors_decode_to_their_fields_and_match_the_node_code(v):
    key = bytes.fromhex(v["key_hex"])
    raw, wire = bytes.fromhex(v["raw_hex"]), bytes.fromhex(v["wire_hex"])
    fields = v["fields"]
    f = decode_raw(raw, {fields["node"]: key})
    for k, want in fields.items():
        got = [list(r) for r in f.ropes] if k == "ropes" else getattr(f, k)
        assert got == want, k
    assert f.authenticated is True
    assert len(wire) <= L.MAX_WIRE_LEN and wire[0] == wire[-1] == 0 and 0 not in wire[1:-1]
    assert decode_wire(wire[1:-1]) == raw
    # Independent checks with the node's own CRC and COBS, binascii and plain hmac.
    assert binascii.crc32(raw[:-4]) == int.from_bytes(raw[-4:], "little")
    mine = bytearray(raw)
    assert node_module("crc32").crc32_into(mine, len(raw) - 4) == len(raw) and mine == raw
    dst = bytearray(1 + len(raw) + len(raw) // 254 + 2)
    n = node_module("cobs").encode_into(raw, len(raw), dst, 1)
    assert bytes(dst[:n]) == wire
    mac_at = len(raw) - L.MAC_LEN - L.CRC_LEN
    assert raw[mac_at: mac_at + L.MAC_LEN] == hmac.new(key, raw[:mac_at], hashlib.sha256).digest()[:4]
    # Independent of the host's structs: the rope records and the tail by hand (layout 3).
    assert raw[0] == 3 and len(raw) == 33 + 10 * len(fields["ropes"])
    for i, r in enumerate(fields["ropes"]):
        assert int.from_bytes(raw[14 + 10 * i + 8: 14 + 10 * i + 10], "little", signed=True) == r[4]
    assert raw[mac_at - 1] == fields["stroke_mask"]


def test_the_vectors_cover_positions_absent_positions_and_stroke_bits():
    good = load_vectors()["good"]
    pos = [r[4] for v in good for r in v["fields"]["ropes"]]
    assert L.POS_ABSENT in pos and any(p > 0 for p in pos if p != L.POS_ABSENT) and any(-32768 < p < 0 for p in pos)
    masks = [v["fields"]["stroke_mask"] for v in good]
    assert any(m & 0x0F for m in masks) and any(m & 0xF0 for m in masks)
    assert len(load_vectors()["good_v2"]) >= 1


@pytest.mark.parametrize("v", load_vectors()["good_v2"], ids=lambda v: v["name"])
def test_version_2_vectors_decode_without_positions(v):
    key = bytes.fromhex(v["key_hex"])
    raw, wire = bytes.fromhex(v["raw_hex"]), bytes.fromhex(v["wire_hex"])
    fields = v["fields"]
    assert raw[0] == 2 and len(raw) == 32 + 8 * len(fields["ropes"])
    f = decode_raw(raw, {fields["node"]: key})
    assert f.version == 2 and f.stroke_mask == 0 and f.authenticated is True
    assert [list(r) for r in f.ropes] == [r + [L.POS_ABSENT] for r in fields["ropes"]]
    assert all(r.position_m is None for r in f.ropes)
    for k, want in fields.items():
        if k != "ropes":
            assert getattr(f, k) == want, k
    dec = StreamDecoder({fields["node"]: key})
    (g,) = dec.feed(wire)
    assert g == f
    from ropemon.station.decoder import frame_bytes
    assert frame_bytes(f) == raw  # what the replay guard compares copies by


def test_bad_vectors_land_in_their_count():
    vec = load_vectors()
    keys = {v["fields"]["node"]: bytes.fromhex(v["key_hex"]) for v in vec["good"] + vec["good_v2"]}
    good = {v["name"]: v for v in vec["good"]}
    for v in vec["bad"]:
        dec = StreamDecoder(keys)
        frames = dec.feed(bytes.fromhex(v["wire_hex"]))
        assert getattr(dec.counts, v["count"]) == 1, (v["name"], dec.counts)
        if "then" in v:  # junk, then a good frame: the frame's leading 0x00 ends the junk
            assert [f.seq for f in frames] == [good[v["then"]]["fields"]["seq"]], v["name"]
            assert dec.counts.frames_ok == 1
        else:
            assert frames == [] and dec.counts.frames_ok == 0, v["name"]
        assert dec.versions == ({v["version"]: 1} if "version" in v else {}), v["name"]
        if "version" in v:
            assert (f"malformed: 1 frame(s) of layout version {v['version']} (this host decodes "
                    "versions 2, 3") in dec.summary()


def test_crc32_check_value_and_residue():
    assert crc32(b"123456789") == 0xCBF43926
    raw, _ = encode_frame(node=1, seq=5, ropes=[(1, 2, 3, 4)])
    assert binascii.crc32(raw) == CRC_RESIDUE  # the decoders' check: one call over the whole frame
    for i in range(len(raw)):
        bad = bytearray(raw)
        bad[i] ^= 0x80
        assert binascii.crc32(bad) != CRC_RESIDUE


def test_a_version_1_frame_is_named_not_taken():
    """A node with the old firmware (CRC-16, 2 bytes shorter): VersionError, not CRC noise."""
    raw, _ = encode_frame(node=1, seq=5, ropes=[(1, 2, 3, 4)], key=KEYS[1], version=2)
    v1 = bytearray(raw[:-4])
    v1[0] = 1
    v1 += binascii.crc_hqx(bytes(v1), 0xFFFF).to_bytes(2, "little")
    with pytest.raises(VersionError, match="layout version 1: this host decodes versions 2, 3 only"):
        decode_raw(bytes(v1), KEYS)
    status_v1 = bytearray(encode_frame(node=1, seq=6, version=2)[0][:-4])  # 30 bytes: shorter than any frame
    status_v1[0] = 1
    status_v1 += binascii.crc_hqx(bytes(status_v1), 0xFFFF).to_bytes(2, "little")
    with pytest.raises(VersionError):
        decode_raw(bytes(status_v1))
    dec = StreamDecoder()
    from cobs import cobs
    assert dec.feed(b"".join(b"\x00" + cobs.encode(bytes(r)) + b"\x00" for r in (v1, status_v1))) == []
    assert dec.counts.malformed == 2 and dec.counts.crc_fail == 0 and dec.versions == {1: 2}
    assert "malformed: 2 frame(s) of layout version 1 (this host decodes versions 2, 3" in dec.summary()


def test_a_mixed_stream_of_version_2_and_3_nodes_decodes_in_order():
    """A mine upgrades one cage at a time: node 1 sends version 3, node 2 still version 2,
    interleaved; both decode, in stream order, each with its own layout's fields."""
    wires, want = [], []
    for k in range(40):
        node, version = (1, 3) if k % 2 == 0 else (2, 2)
        ropes = [(4000 + k, 3990, 4010, 5000 + i) + ((k * 10 - 200 + i,) if version == 3 else ()) for i in range(4)]
        mask = (1 << (k % 8)) if version == 3 else 0
        wires.append(encode_frame(node=node, seq=k + 1, ropes=ropes, key=KEYS[node], version=version,
                                  stroke_mask=mask, status=L.ST_STROKE_LIMIT if mask else 0)[1])
        want.append((node, version, k + 1, [r[4] if version == 3 else L.POS_ABSENT for r in ropes], mask))
    data = b"".join(wires)
    for chunk in (1, 7, 4096):
        dec = StreamDecoder(KEYS)
        got = [f for i in range(0, len(data), chunk) for f in dec.feed(data[i:i + chunk])]
        assert [(f.node, f.version, f.seq, [r.pos_01mm for r in f.ropes], f.stroke_mask) for f in got] == want
        assert dec.counts.frames_ok == 40 and dec.counts.malformed == dec.counts.crc_fail == 0
    from ropemon.station.batch import decode_bytes
    b = decode_bytes(data, KEYS)
    assert [(f.node, f.version, f.seq, [r.pos_01mm for r in f.ropes], f.stroke_mask) for f in b.frames()] == want
    assert b.counts == dec.counts
    # a damaged frame of either version is dropped (CRC, or its COBS chain), and the rest still decode
    for at in (5, len(wires[0]) + 5, len(wires[0]) + 20):  # inside the first version 3, then version 2 frame
        bad = bytearray(data)
        bad[at] ^= 0x10
        dec = StreamDecoder(KEYS)
        assert len(dec.feed(bytes(bad))) == 39 and dec.counts.crc_fail + dec.counts.malformed == 1


def test_positions_and_stroke_bits():
    raw, _ = encode_frame(node=1, seq=5, ropes=[Rope(100, 90, 110, 5, -1234), Rope(200, 190, 210, 6),
                                                (300, 290, 310, 7, 32767)],
                          stroke_mask=(1 << L.STROKE_LOW_SHIFT) | (1 << (L.STROKE_HIGH_SHIFT + 2)),
                          status=L.ST_STROKE_LIMIT)
    f = decode_raw(raw)
    assert f.version == 3 and [r.pos_01mm for r in f.ropes] == [-1234, L.POS_ABSENT, 32767]
    assert f.ropes[0].position_m == pytest.approx(-0.1234) and f.ropes[1].position_m is None
    assert f.stroke_low == [True, False, False] and f.stroke_high == [False, False, True]
    assert "stroke_limit" in f.status_flags
    d = f.to_dict()
    assert d["stroke_mask"] == 0x41 and d["ropes"][0]["pos_01mm"] == -1234
    assert d["ropes"][1]["position_absent"] is True and d["ropes"][0]["position_absent"] is False
    json.dumps(d)
    # a version 2 frame cannot carry either
    with pytest.raises(ValueError, match="no piston position"):
        encode_frame(node=1, seq=1, ropes=[(1, 2, 3, 4, 5)], version=2)
    with pytest.raises(ValueError, match="no stroke_mask"):
        encode_frame(node=1, seq=1, ropes=[(1, 2, 3, 4)], version=2, stroke_mask=1)
    # the default Rope and Frame of code written before positions: absent, 0
    assert Rope(1, 2, 3, 4).pos_01mm == L.POS_ABSENT
    from ropemon.station.protocol import Frame
    assert Frame(3, 0, 1, 0, 1, 0, 0, (), 0, 0, 0, 0).stroke_mask == 0


def test_length_is_checked_for_the_version_byte():
    """CRC intact, version 2 or 3, but the other version's length (or none): malformed, named."""
    raw3, _ = encode_frame(node=1, seq=5, ropes=[(1, 2, 3, 4, 5)] * 2)
    raw2, _ = encode_frame(node=1, seq=5, ropes=[(1, 2, 3, 4)] * 2, version=2)

    def recrc(b: bytes) -> bytes:
        return b[:-4] + crc32(b[:-4]).to_bytes(4, "little")

    with pytest.raises(MalformedError, match="length 53 is not a version 2 frame's"):
        decode_raw(recrc(b"\x02" + raw3[1:]))
    with pytest.raises(MalformedError, match="length 48 is not a version 3 frame's"):
        decode_raw(recrc(b"\x03" + raw2[1:]))
    with pytest.raises(VersionError, match="layout version 4"):
        decode_raw(recrc(b"\x04" + raw3[1:]))
    assert decode_raw(raw2).version == 2 and decode_raw(raw3).version == 3
    # the batch decoder counts them as the streaming decoder does
    from cobs import cobs
    from ropemon.station.batch import decode_bytes
    bad = [recrc(b"\x02" + raw3[1:]), recrc(b"\x03" + raw2[1:]), recrc(b"\x04" + raw3[1:]), raw2, raw3]
    data = b"".join(b"\x00" + cobs.encode(r) + b"\x00" for r in bad)
    dec = StreamDecoder()
    assert [f.version for f in dec.feed(data)] == [2, 3]
    assert dec.counts.malformed == 3 and dec.versions == {4: 1}
    b = decode_bytes(data)
    assert b.counts == dec.counts and [f.version for f in b.frames()] == [2, 3]


def test_junk_without_a_delimiter_does_not_cost_the_next_frame():
    """Noise with no 0x00 in it, then a frame: the frame's leading 0x00 ends the junk."""
    _, wire = encode_frame(node=1, seq=9, ropes=[(1, 2, 3, 4)], key=KEYS[1])
    for junk in (b"\x55", b"\x13\x37" * 7, bytes(range(1, 256)), wire[1:30]):
        dec = StreamDecoder(KEYS)
        got = dec.feed(junk + wire)
        assert [f.seq for f in got] == [9], junk
        c = dec.counts
        assert c.frames_ok == 1 and c.crc_fail + c.malformed == 1 and c.mac_fail == 0
        assert c.bytes_discarded == len(junk) + 1  # the junk and the 0x00 that ended it; the frame's own: none
    # Idle delimiters (back-to-back frames give 0x00 0x00) are neither frames nor discarded.
    dec = StreamDecoder(KEYS)
    assert len(dec.feed(wire + b"\x00" * 5 + encode_frame(node=1, seq=10, key=KEYS[1])[1])) == 2
    assert dec.counts.as_dict() == dict(dec.counts.as_dict(), frames_ok=2) and dec.counts.bytes_discarded == 0


def test_decode_raw_errors_are_specific():
    raw, _ = encode_frame(node=1, seq=5, ropes=[(1, 2, 3, 4)], key=KEYS[1])
    assert decode_raw(raw, KEYS).authenticated is True
    assert decode_raw(raw).authenticated is None
    bad = bytearray(raw)
    bad[5] ^= 1
    with pytest.raises(CrcError):
        decode_raw(bytes(bad))
    with pytest.raises(MalformedError):
        decode_raw(raw[:20])
    with pytest.raises(MacError, match="MAC mismatch"):
        decode_raw(raw, {1: bytes(16)})
    with pytest.raises(MacError, match="no key"):
        decode_raw(raw, {2: KEYS[2]})
    # Valid CRC, impossible length (one byte too many).
    odd = raw[:-4] + b"\x00"
    odd += crc32(odd).to_bytes(4, "little")
    with pytest.raises(MalformedError):
        decode_raw(odd)
    # Status frame carrying ropes is refused.
    wrong_kind, _ = encode_frame(node=1, seq=5, ropes=[(1, 2, 3, 4)], kind=L.KIND_STATUS)
    with pytest.raises(MalformedError, match="status frame"):
        decode_raw(wrong_kind)


def test_frame_conveniences():
    raw, _ = encode_frame(node=1, seq=5, ropes=[Rope(100, 90, 110, 5), Rope(200, 190, 210, 6)],
                          status=L.ST_BATTERY_LOW | L.ST_IMBALANCE, oil_temp_cc=-150)
    f = decode_raw(raw)
    assert f.status_flags == ["battery_low", "imbalance"]
    assert f.tensions_n == [1000, 2000]
    assert f.total_dan == 300
    assert f.oil_temp_c == -1.5
    d = f.to_dict()
    assert d["node"] == 1 and d["seq"] == 5 and d["ropes"][1]["raw_kpa"] == 6
    assert d["ropes"][1]["absent"] is False
    raw, _ = encode_frame(node=1, seq=6)
    assert decode_raw(raw).oil_temp_c is None and decode_raw(raw).kind == L.KIND_STATUS


def test_replayed_and_forged_frames_are_dropped_and_counted():
    frames = frame_set(11, 6, keyed=True)
    dec = StreamDecoder(KEYS)
    assert len(dec.feed(b"".join(w for _, w in frames))) == 6
    assert dec.feed(frames[2][1]) == []  # an exact copy of a frame just taken: a radio retry
    assert dec.counts.duplicate == 1 and dec.counts.replayed == 0
    old = decode_raw(frames[2][0], KEYS)
    other = encode_frame(node=old.node, seq=old.seq, ropes=[(1, 1, 1, 1)], key=KEYS[old.node])[1]
    assert dec.feed(other) == []  # an old seq with other bytes: a replay
    assert dec.counts.replayed == 1
    forged, wire = encode_frame(node=1, seq=10**6, ropes=[(1, 1, 1, 1)], key=bytes(16))
    assert dec.feed(wire) == []
    assert dec.counts.mac_fail == 1
    stranger = encode_frame(node=9, seq=1, key=KEYS[1])[1]
    assert dec.feed(stranger) == []
    assert dec.counts.mac_fail == 2
    assert dec.authenticity_checked and "MAC checked" in dec.summary()
    plain = StreamDecoder()
    assert [f.authenticated for f in plain.feed(frames[0][1] * 2)] == [None, None]  # no replay check without keys
    assert "NOT checked" in plain.summary()


def test_replay_guard_accepts_only_newer_seq_per_node():
    g = ReplayGuard()
    assert g.accept(1, 100)
    assert not g.accept(1, 98)      # late: no reordering window
    assert not g.accept(1, 100)     # twice
    assert g.accept(1, 200)         # a jump (frames lost) is fine
    assert not g.accept(1, 199)
    assert g.accept(2, 0)           # nodes are independent


def test_finish_counts_an_unterminated_tail():
    _, wire = encode_frame(node=1, seq=1, ropes=[(1, 2, 3, 4)])
    dec = StreamDecoder()
    assert dec.feed(wire + wire[:10]) != []
    dec.finish()
    # wire[:10]: the leading 0x00 (an idle delimiter) and 9 bytes of a body never ended
    assert dec.counts.malformed == 1 and dec.counts.bytes_discarded == 9


def test_a_seq_restarting_at_0_is_refused_as_a_replay():
    """The node's seq never restarts (boot counter in its top bits, docs/protocol.md): frames
    whose seq goes back to 0 after an authenticated run are replays, counted and dropped."""
    key = KEYS[1]
    wires = [encode_frame(node=1, seq=s, ropes=[(1, 1, 1, 1)], key=key)[1] for s in range(200)]
    after_reset = [encode_frame(node=1, seq=s, time_ms=5, ropes=[(2, 2, 2, 2)], key=key)[1] for s in range(3)]
    strict = StreamDecoder(KEYS)
    assert len(strict.feed(b"".join(wires))) == 200
    assert strict.feed(b"".join(after_reset)) == [] and strict.counts.replayed == 3


def test_keys_from_options_merges_key_and_config_options(tmp_path):
    from ropemon.commission.nodejson import seal
    from ropemon.station.protocol import keys_from_options

    def key_file(name: str, text: str) -> str:
        p = tmp_path / name
        p.write_text(text)
        p.chmod(0o600)
        return str(p)

    k1, k2, k21, zz = (key_file(n, t) for n, t in (("k1", KEYS[1].hex()), ("k2", KEYS[2].hex()),
                                                   ("k21", KEYS[1].hex()), ("zz", "zz")))
    cfg = tmp_path / "node2.json"
    cfg.write_text(json.dumps(seal({"node": {"node_id": 2, "key": list(KEYS[2])}})))
    assert keys_from_options([], [], env={}) == {}
    got = keys_from_options([f"1:{k1}"], [str(cfg)], env={})
    assert got == {1: KEYS[1], 2: KEYS[2]}
    assert keys_from_options([f"2:{k2}"], [str(cfg)], env={}) == {2: KEYS[2]}  # same key twice: fine
    with pytest.raises(ValueError, match="node 2: --key-file 2:.* and --config .*node2.json give different keys"):
        keys_from_options([f"2:{k21}"], [str(cfg)], env={})
    with pytest.raises(ValueError, match="not hex"):
        keys_from_options([f"1:{zz}"], [], env={})
    with pytest.raises(ValueError, match="cannot read"):
        keys_from_options([], [str(tmp_path / "none.json")], env={})
    with pytest.raises(ValueError, match="--accept-rewound needs node keys"):
        keys_from_options([], [], accept_rewound=[1], env={})
    assert keys_from_options([f"1:{k1}"], [], accept_rewound=[1], env={}) == {1: KEYS[1]}


def test_ropemon_decode_prints_positions_and_stroke_bits_of_both_versions(tmp_path):
    """`ropemon decode` of a capture of a version 3 and a version 2 node: one JSON line each, with
    pos_01mm, position_absent and stroke_mask (absent / 0 for the version 2 node)."""
    import subprocess
    import sys

    data = (encode_frame(node=1, seq=1, ropes=[(4000, 3990, 4010, 5000, 905), (4000, 3990, 4010, 5000, L.POS_ABSENT)],
                         stroke_mask=1 << L.STROKE_HIGH_SHIFT, status=L.ST_STROKE_LIMIT)[1]
            + encode_frame(node=2, seq=1, ropes=[(4000, 3990, 4010, 5000)], version=2)[1])
    p = tmp_path / "cap.bin"
    p.write_bytes(data)
    r = subprocess.run([sys.executable, "-m", "ropemon.cli", "decode", str(p)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    v3, v2 = [json.loads(x) for x in r.stdout.splitlines()]
    assert (v3["version"], v3["stroke_mask"], v3["status_flags"]) == (3, 0x10, ["stroke_limit"])
    assert [(x["pos_01mm"], x["position_absent"]) for x in v3["ropes"]] == [(905, False), (L.POS_ABSENT, True)]
    assert (v2["version"], v2["stroke_mask"]) == (2, 0)
    assert [(x["pos_01mm"], x["position_absent"]) for x in v2["ropes"]] == [(L.POS_ABSENT, True)]
    assert "frames_ok=2" in r.stderr
