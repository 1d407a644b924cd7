"""A refused node.json: the host, holding the node's key, authenticates the CONFIG FAULT frames.

The node signs its config-fault status frames with the refused file's node_id
and key when those are still valid (config.load_for_boot); only without them
it sends as node 255, unkeyed, which a keyed host drops as a MAC failure.
"""
from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from ropemon.station import protocol
from ropemon.firmware import FIRMWARE_DIR, node_module

L = node_module("layout")
config = node_module("config")
crc16 = node_module("crc16").crc16
DOC = json.loads((FIRMWARE_DIR / "node.json").read_text())
KEYS = {DOC["node"]["node_id"]: bytes(DOC["node"]["key"])}


def _rsens(path: Path, seconds: int) -> Path:
    n = DOC["node"]["ropes"]
    rec = struct.pack("<%dH" % (2 * n + 4), *([30000] * (2 * n) + [60000, 0xFFFF, 0, 0]))
    path.write_bytes(struct.pack("<4sHHHH", b"RSNS", 1, n, 200, 0) + rec * (200 * seconds))
    return path


def _bad_field(doc: dict) -> dict:
    doc = json.loads(json.dumps(doc))
    doc["node"]["p_kpa_max"] = 0
    doc["crc"] = crc16(config.canonical(doc["node"]))
    return doc


def _bad_crc(doc: dict) -> dict:
    doc = json.loads(json.dumps(doc))
    doc["crc"] ^= 1
    return doc


def _frames(wire: bytes, keys):
    return [protocol.decode_raw(protocol.decode_wire(b), keys) for b in wire.split(b"\x00") if b]


@pytest.mark.parametrize("make", [_bad_crc, _bad_field])
def test_host_authenticates_config_fault_frames_of_a_refused_file(tmp_path, make):
    cfg_path = tmp_path / "node.json"
    cfg_path.write_text(json.dumps(make(DOC)))
    hal_sim = node_module("hal_sim")
    out = tmp_path / "out.bin"
    assert hal_sim.run_sim(str(cfg_path), str(_rsens(tmp_path / "in.rsens", 1)), str(out)) == (200, 10)
    frames = _frames(out.read_bytes(), KEYS)
    assert len(frames) == 10
    for f in frames:
        assert f.authenticated and f.node == 1
        assert f.kind == L.KIND_STATUS and f.status & L.ST_CONFIG_FAULT
    assert [f.seq for f in frames] == list(range(10))


def test_without_a_readable_identity_frames_are_node_255_and_a_keyed_host_refuses_them(tmp_path):
    doc = json.loads(json.dumps(DOC))
    doc["node"]["key"] = [1] * 8   # too short: no identity to sign with
    cfg_path = tmp_path / "node.json"
    cfg_path.write_text(json.dumps(doc))
    for path in (cfg_path, tmp_path / "missing.json"):
        out = tmp_path / "out.bin"
        node_module("hal_sim").run_sim(str(path), str(_rsens(tmp_path / "in.rsens", 1)), str(out))
        frames = _frames(out.read_bytes(), None)
        assert len(frames) == 10 and all(f.node == 255 and f.status & L.ST_CONFIG_FAULT for f in frames)
        with pytest.raises(protocol.MacError):
            _frames(out.read_bytes(), KEYS)


def test_replay_under_micropython_sends_authenticated_config_fault_frames(tmp_path):
    cfg_path = tmp_path / "node.json"
    cfg_path.write_text(json.dumps(_bad_field(DOC)))
    out = tmp_path / "out.bin"
    r = subprocess.run([str(Path(sys.executable).parent / "ropemon"), "replay", str(_rsens(tmp_path / "in.rsens", 1)),
                        "--out", str(out), "--config", str(cfg_path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "node.p_kpa_max" in r.stderr and "as node 1, signed" in r.stderr
    frames = _frames(out.read_bytes(), KEYS)
    assert len(frames) == 10 and all(f.authenticated and f.status & L.ST_CONFIG_FAULT for f in frames)
