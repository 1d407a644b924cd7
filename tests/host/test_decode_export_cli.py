"""`ropemon decode` and `ropemon export` as a user runs them."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from host_rig import KEYS, frame_set
from ropemon.station.decoder import StreamDecoder
from ropemon.station.protocol import L
from ropemon.station.store import Store


def ropemon(*args, stdin: bytes | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ropemon.cli", *args], input=stdin,
                          capture_output=True, timeout=60)


def key_files(tmp_path: Path, keys: dict[int, bytes]) -> list[str]:
    """--key-file NODE:PATH options for `keys`, each file holding the key in hex, mode 0600."""
    out = []
    for node, key in keys.items():
        p = tmp_path / f"node{node}.key"
        p.write_text(key.hex() if isinstance(key, bytes) else key)
        p.chmod(0o600)
        out.append(f"--key-file={node}:{p}")
    return out


def node_json(path: Path, node: int, key: bytes) -> Path:
    """A node.json holding only what the key readers need: the node section's id and key, sealed."""
    from ropemon.commission.nodejson import seal
    path.write_text(json.dumps(seal({"schema": 1, "physical": {}, "node": {"node_id": node, "key": list(key)}})))
    return path


def capture(keyed: bool = False) -> tuple[bytes, list]:
    frames = frame_set(5, 40, keyed)
    data = b"\x13\x37junk\x00" + b"".join(w for _, w in frames[:20]) + b"\x01\x02\x03\x00" + \
        b"".join(w for _, w in frames[20:])
    return data, StreamDecoder(KEYS if keyed else None).feed(data)


def test_decode_file_gives_json_lines_and_counts(tmp_path):
    data, want = capture()
    p = tmp_path / "cap.bin"
    p.write_bytes(data)
    r = ropemon("decode", str(p))
    assert r.returncode == 0, r.stderr
    rows = [json.loads(x) for x in r.stdout.decode().splitlines()]
    assert len(rows) == 40 == len(want)
    assert rows == [f.to_dict() for f in want]
    for k in ("node", "seq", "time_ms", "status", "fault_mask", "ropes", "depth_mm", "speed_mm_s",
              "battery_mv", "oil_temp_cc", "authenticated"):
        assert k in rows[0]
    err = r.stderr.decode()
    assert "frames_ok=40" in err and "malformed=2" in err and "NOT checked" in err


def test_decode_stdin_with_keys(tmp_path):
    data, want = capture(keyed=True)
    keys = key_files(tmp_path, KEYS)
    r = ropemon("decode", "-", *keys, stdin=data)
    assert r.returncode == 0, r.stderr
    rows = [json.loads(x) for x in r.stdout.decode().splitlines()]
    assert len(rows) == 40 and all(row["authenticated"] is True for row in rows)
    assert "MAC checked" in r.stderr.decode()
    # wrong key: every frame refused, counted, and exit 1 saying the key is probably wrong
    r = ropemon("decode", "-", *key_files(tmp_path, {1: bytes(16), 2: bytes(16)}), stdin=data)
    assert r.returncode == 1 and r.stdout == b"" and "mac_fail=40" in r.stderr.decode()
    assert b"all 40 frame(s) failed authentication" in r.stderr and b"key is probably wrong" in r.stderr


def test_decode_unreadable_input_fails_clearly(tmp_path):
    r = ropemon("decode", str(tmp_path / "missing.bin"))
    assert r.returncode == 2 and b"cannot read" in r.stderr and b"missing.bin" in r.stderr
    r = ropemon("decode", str(tmp_path))
    assert r.returncode == 2 and b"cannot read" in r.stderr
    r = ropemon("decode", "-", *key_files(tmp_path, {1: "zz"}))
    assert r.returncode == 2 and b"not hex" in r.stderr


def test_export_csv(tmp_path):
    _, frames = capture()
    db = tmp_path / "a.db"
    with Store(db) as s:
        for i, f in enumerate(frames):
            s.add_frame("pithead", f, float(i))
    r = ropemon("export", str(db), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    lines = (tmp_path / "out" / "frames.csv").read_text().splitlines()
    assert len(lines) == 41 and lines[0].startswith("id,rx_time,rx_time_utc,receiver,node,seq")
    assert f"r{L.MAX_ROPES}_raw_kpa" in lines[0] and "r0_" not in lines[0]     # ropes from 1, as on the cage
    assert lines[2].split(",")[2] == "1970-01-01T00:00:01.000Z"
    r = ropemon("export", str(tmp_path / "nope.db"), "--out", str(tmp_path / "o2"))
    assert r.returncode == 2 and b"no such database" in r.stderr


def test_decode_with_keys_from_node_json(tmp_path):
    data, _ = capture(keyed=True)
    cfgs = []
    for node, key in KEYS.items():
        p = node_json(tmp_path / f"node{node}.json", node, key)
        cfgs += ["--config", str(p)]
    r = ropemon("decode", "-", *cfgs, stdin=data)
    assert r.returncode == 0 and len(r.stdout.splitlines()) == 40 and b"MAC checked" in r.stderr
    r = ropemon("decode", "-", "--config", str(tmp_path / "none.json"), stdin=data)
    assert r.returncode == 2 and b"cannot read" in r.stderr
    node_json(tmp_path / "bad.json", 300, KEYS[1])
    r = ropemon("decode", "-", "--config", str(tmp_path / "bad.json"), stdin=data)
    assert r.returncode == 2 and b"node.node_id" in r.stderr


def test_decode_accept_rewound(tmp_path):
    from ropemon.station.decoder import SEQ_COUNT_BITS
    from ropemon.station.protocol import encode_frame

    def w(boot, k):
        return encode_frame(node=1, seq=(boot << SEQ_COUNT_BITS) | k, ropes=[(1, 1, 1, 1)], key=KEYS[1])[1]

    data = b"".join([w(7, 0), w(7, 1), w(0, 0), w(0, 1)])  # node 1's flash was wiped after boot 7
    keys = key_files(tmp_path, {1: KEYS[1]})
    r = ropemon("decode", "-", *keys, stdin=data)
    assert r.returncode == 0 and len(r.stdout.splitlines()) == 2
    err = r.stderr.decode()
    assert "rewound=2" in err and "node 1 REFUSED" in err
    r = ropemon("decode", "-", *keys, "--accept-rewound", "1", stdin=data)
    assert r.returncode == 0, r.stderr
    assert [json.loads(x)["seq"] for x in r.stdout.splitlines()] == [7 << SEQ_COUNT_BITS, (7 << SEQ_COUNT_BITS) | 1, 0, 1]
    assert "rewound=0" in r.stderr.decode() and "replayed=0" in r.stderr.decode()
    r = ropemon("decode", "-", "--accept-rewound", "1", stdin=data)
    assert r.returncode == 2 and b"needs node keys" in r.stderr
    r = ropemon("decode", "-", *keys, "--accept-rewound", "x", stdin=data)
    assert r.returncode == 2 and b"node id" in r.stderr
