"""`ropemon replay`: the firmware in micropython (and CPython) on a sensor stream."""
import json
import struct

import pytest

from ropemon.cli import main
from ropemon.demo import read_frames_bin
from ropemon.firmware import FIRMWARE_DIR
from ropemon.protocol import L

CONFIG = FIRMWARE_DIR / "node.json"


def rsens(path, samples=400, ropes=4, hz=200):
    head = struct.pack("<4sHHHH", b"RSNS", 1, ropes, hz, 0)
    rec = [20000] * ropes + [30000] * ropes + [40000, 0xFFFF, 0, 0]
    path.write_bytes(head + struct.pack("<%dH" % len(rec), *rec) * samples)
    return path


@pytest.mark.parametrize("interp", ["micropython", "cpython"])
def test_replay_writes_one_frame_per_window(tmp_path, capsys, interp):
    phys = json.loads(CONFIG.read_text())["physical"]
    window = phys["sample_hz"] // phys["frame_hz"]
    out = tmp_path / "f.bin"
    assert main(["replay", str(rsens(tmp_path / "s.rsens", samples=10 * window, hz=phys["sample_hz"])),
                 "--out", str(out), "--interpreter", interp]) == 0
    assert "-> 10 frames" in capsys.readouterr().out
    sent = read_frames_bin(out, {phys["node_id"]: bytes.fromhex(phys["key_hex"])})
    assert [f.seq for f in sent.frames] == list(range(10))
    assert all(f.kind == L.KIND_DATA and len(f.ropes) == phys["ropes"] for f in sent.frames)


def test_refused_config_gives_status_frames_and_says_why(tmp_path, capsys):
    doc = json.loads(CONFIG.read_text())
    doc["crc"] ^= 1
    bad = tmp_path / "node.json"
    bad.write_text(json.dumps(doc))
    out = tmp_path / "f.bin"
    assert main(["replay", str(rsens(tmp_path / "s.rsens", samples=100)), "--out", str(out),
                 "--config", str(bad)]) == 0
    assert "crc" in capsys.readouterr().err.lower()
    frames = read_frames_bin(out).frames
    assert frames and all(f.kind == L.KIND_STATUS and f.status & L.ST_CONFIG_FAULT for f in frames)


def test_bad_inputs_are_refused_with_the_reason(tmp_path, capsys):
    junk = tmp_path / "junk.rsens"
    junk.write_bytes(b"hello world, not a stream")
    assert main(["replay", str(junk), "--out", str(tmp_path / "o.bin")]) == 1
    assert "not a sensor stream" in capsys.readouterr().err
    assert main(["replay", str(tmp_path / "missing.rsens"), "--out", str(tmp_path / "o.bin")]) == 1
    assert "cannot read" in capsys.readouterr().err
    s = rsens(tmp_path / "s.rsens", samples=10)
    assert main(["replay", str(s), "--out", str(tmp_path / "o.bin"), "--config", str(tmp_path / "nope.json")]) == 1
    assert "no such config file" in capsys.readouterr().err
    three = rsens(tmp_path / "three.rsens", samples=10, ropes=3)
    assert main(["replay", str(three), "--out", str(tmp_path / "o.bin")]) == 1
    assert "3 ropes" in capsys.readouterr().err
