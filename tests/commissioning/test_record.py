"""`ropemon record`: arm a node's recording and fetch it, against the virtual node (the
MicroPython unix port behind a pty, driven by the pinned mpremote)."""
from __future__ import annotations

import array

import numpy as np

from ropemon.cli import main
from ropemon.firmware import node_module
from ropemon.commission.reference import read_rsens
from ropemon.lab.virtualnode import VirtualNode


def test_arm_then_fetch_a_recording(tmp_path, capsys):
    rs = node_module("rsens")
    root = tmp_path / "node"
    with VirtualNode(root) as node:
        assert main(["record", "--port", node.port, "--seconds", "90"]) == 0
        assert (root / rs.RECORD_FLAG).read_text() == "90\n"
        assert rs.armed_seconds(str(root / rs.RECORD_FLAG)) == 90
        assert "armed: the node records the first 90 s after its next boot" in capsys.readouterr().out
        # at its next boot the board HAL (hal_board._recorder) takes the flag and records;
        # here the node's own writer puts 2 s of a 4-rope stream where it would
        recs = [array.array("H", [(k * 37 + j) & 0xFFFF for j in range(12)]) for k in range(400)]
        w = rs.Writer(open(root / rs.RECORD_FILE, "wb"), 4, 200, len(recs))
        for r in recs:
            w.add(r)
        out = tmp_path / "wind.rsens"
        assert main(["record", "--port", node.port, "--fetch", "--out", str(out)]) == 0
        assert f"{out}: 400 samples (2.0 s) of 4 ropes at 200 Hz" in capsys.readouterr().out
        ropes, hz, got = read_rsens(out)
        assert (ropes, hz) == (4, 200) and np.array_equal(got, np.array([list(r) for r in recs]))
        # a recording cut within a record (still being written) is refused, nothing written
        data = (root / rs.RECORD_FILE).read_bytes()
        (root / rs.RECORD_FILE).write_bytes(data[:-6])
        out.unlink()
        assert main(["record", "--port", node.port, "--fetch", "--out", str(out)]) == 1
        assert "ends within a record" in capsys.readouterr().err and not out.exists()
        # no recording on the node
        (root / rs.RECORD_FILE).unlink()
        assert main(["record", "--port", node.port, "--fetch", "--out", str(out)]) == 1
        assert "copying wind.rsens off the node" in capsys.readouterr().err


def test_bad_arguments_are_refused(tmp_path, capsys):
    with VirtualNode(tmp_path / "node") as node:
        assert main(["record", "--port", node.port, "--seconds", "601"]) == 1
        assert "--seconds: must be 1 .. 600, got 601" in capsys.readouterr().err
        assert main(["record", "--port", node.port, "--fetch"]) == 1
        assert "--fetch needs --out" in capsys.readouterr().err
    assert not (tmp_path / "node" / "record").exists()
