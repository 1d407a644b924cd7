"""Strict replay protection: seq monotonic across node resets (boot counter), refused rewinds,
operator acceptance, and the firmware's boot counter end to end under `micropython`."""
from __future__ import annotations

import json
import struct
import subprocess
from pathlib import Path

import pytest

from host_framegen import KEYS
from ropemon.alarms import AlarmEngine, AlarmSettings, Timing
from ropemon.decoder import SEQ_COUNT_BITS, ReplayGuard, StreamDecoder
from ropemon.firmware import FIRMWARE_DIR
from ropemon.protocol import encode_frame
from ropemon.virtualnode import micropython_command


def wires(node: int, seqs, key: bytes | None = None) -> list[bytes]:
    return [encode_frame(node=node, seq=s, ropes=[(1, 1, 1, 1)], key=KEYS[node] if key is None else key)[1]
            for s in seqs]


def boot(b: int, k: int) -> int:
    return (b << SEQ_COUNT_BITS) | k


def test_strict_by_default_with_keys():
    dec = StreamDecoder(KEYS)
    w = wires(1, range(10, 20))
    assert [f.seq for f in dec.feed(b"".join(w))] == list(range(10, 20))
    # Not newer than the last accepted: dropped, even one step back (no reordering window).
    assert dec.feed(w[-2] + w[-1] + w[0]) == []
    assert dec.counts.replayed == 3 and dec.counts.rewound == 0 and dec.replay.rewound == {}
    assert [f.seq for f in dec.feed(b"".join(wires(1, [25])))] == [25]  # a gap is fine
    assert dec.counts.restarts == 0
    assert [f.seq for f in dec.feed(b"".join(wires(2, [0])))] == [0]  # nodes are independent


def test_a_node_reset_continues_and_a_recorded_earlier_boot_is_refused():
    dec = StreamDecoder(KEYS)
    boot0 = wires(1, [boot(0, k) for k in range(5)])
    boot1 = wires(1, [boot(1, k) for k in range(3)])
    assert len(dec.feed(b"".join(boot0 + boot1))) == 8  # the reset needs no special case
    assert dec.feed(b"".join(boot0)) == []              # replaying the recorded first boot
    assert dec.counts.replayed == 5 and dec.counts.rewound == 5
    assert dec.replay.rewound == {1: (1, 0)}
    assert "node 1 REFUSED: its boot counter went back from 1 to 0" in dec.summary()
    assert "an operator must accept node 1" in dec.summary()
    assert [f.seq for f in dec.feed(boot1[-1] + b"".join(wires(1, [boot(1, 3)])))] == [boot(1, 3)]
    assert dec.counts.replayed == 6  # the repeated boot-1 frame; the node is fine again
    assert dec.replay.rewound == {}


def test_a_wiped_node_is_refused_until_the_operator_accepts_it():
    dec = StreamDecoder(KEYS)
    assert len(dec.feed(b"".join(wires(1, [boot(7, k) for k in range(3)])))) == 3
    wiped = wires(1, [boot(0, k) for k in range(6)])  # flash wiped: boot counter back to 0
    assert dec.feed(b"".join(wiped[:3])) == []
    assert dec.counts.rewound == 3 and dec.replay.rewound == {1: (7, 0)}
    dec.replay.accept_rewound(1)  # the operator checked the node: take its next frame as the baseline
    assert [f.seq for f in dec.feed(b"".join(wiped[3:]))] == [boot(0, 3), boot(0, 4), boot(0, 5)]
    assert dec.replay.rewound == {}
    assert dec.feed(wiped[0]) == []  # strict again: once accepted, older frames are replays
    assert dec.counts.replayed == 4
    # The same decision given up front.
    pre = StreamDecoder(KEYS, accept_rewound=[1])
    assert len(pre.feed(b"".join(wires(1, [boot(7, 0)]) + wiped[:2]))) == 1
    pre2 = StreamDecoder(KEYS)
    pre2.feed(b"".join(wires(1, [boot(7, 0)])))
    pre2.replay.accept_rewound(1)
    assert len(pre2.feed(b"".join(wiped[:2]))) == 2


def test_a_forged_frame_cannot_use_the_operator_acceptance():
    dec = StreamDecoder(KEYS, accept_rewound=[1])
    assert dec.feed(b"".join(wires(1, [5], key=bytes(16)))) == []  # wrong key: MAC fails first
    assert dec.counts.mac_fail == 1
    assert len(dec.feed(b"".join(wires(1, [boot(3, 0), boot(2, 0)])))) == 1


def test_refusals_raise_the_link_integrity_alarm():
    eng = AlarmEngine(AlarmSettings(link_timing=Timing(raise_after_s=0, clear_after_s=10, min_frames=1)))
    dec = StreamDecoder(KEYS)
    dec.feed(b"".join(wires(1, [boot(2, 0)])))
    assert eng.update_link("pithead", dec.counts.mac_fail, dec.counts.replayed, 1.0) == []
    dec.feed(b"".join(wires(1, [boot(1, 0)])))
    ev = eng.update_link("pithead", dec.counts.mac_fail, dec.counts.replayed, 2.0)
    assert [(e.action, e.alarm) for e in ev] == [("raise", "link_integrity:pithead")]


def test_without_keys_nothing_is_refused_and_legacy_mode_still_exists():
    plain = StreamDecoder()
    w = wires(1, [5, 5, 1])
    assert [f.seq for f in plain.feed(b"".join(w))] == [5, 5, 1]
    assert "NOT checked" in plain.summary()
    legacy = ReplayGuard(accept_restarts=True)
    assert legacy.accept(1, 500) and legacy.accept(1, 0) and legacy.restarts == 1
    strict = ReplayGuard()
    assert strict.accept(1, 500) and not strict.accept(1, 0) and strict.restarts == 0


# --- the firmware's boot counter, end to end under the real micropython

def _rsens(path: Path, phys: dict, seconds: float) -> None:
    """A cage at rest, mid-scale counts on every loop (docs/data-formats.md)."""
    n, hz = phys["ropes"], phys["sample_hz"]
    words = [30000] * (2 * n) + [60000, 0xFFFF, 0, 0]
    path.write_bytes(struct.pack("<4sHHHH", b"RSNS", 1, n, hz, 0)
                     + struct.pack(f"<{2 * n + 4}H", *words) * int(seconds * hz))


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bootseq")
    doc = json.loads((FIRMWARE_DIR / "node.json").read_text())
    _rsens(tmp / "rest.rsens", doc["physical"], seconds=0.5)
    keys = {doc["node"]["node_id"]: bytes.fromhex(doc["physical"]["key_hex"])}

    def run(out: str, *opts: str) -> bytes:
        r = subprocess.run([micropython_command(), "-m", "ropenode.sim_main", *opts,
                            str(FIRMWARE_DIR / "node.json"), str(tmp / "rest.rsens"), str(tmp / out)],
                           env={"MICROPYPATH": str(FIRMWARE_DIR)}, capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stdout + r.stderr
        assert r.stdout.split()[-4:] == ["samples", "100", "frames", "5"]
        return (tmp / out).read_bytes()

    return tmp, keys, run


def test_sim_runs_with_a_boot_file_are_successive_boots(sim):
    tmp, keys, run = sim
    boot_file = str(tmp / "bootcount")
    runs = [run(f"boot{i}.bin", "--boot-file", boot_file) for i in range(3)]
    assert (tmp / "bootcount").read_text() == "2\n"
    dec = StreamDecoder(keys)
    frames = [f for data in runs for f in dec.feed(data)]
    assert [f.seq for f in frames] == [boot(b, k) for b in range(3) for k in range(5)]
    assert dec.feed(runs[0]) == [] and dec.counts.replayed == 5 and dec.counts.rewound == 5


def test_sim_without_a_boot_file_is_deterministic_and_a_rerun_is_a_replay(sim):
    tmp, keys, run = sim
    a, b = run("a.bin"), run("b.bin")
    assert a == b
    dec = StreamDecoder(keys)
    assert [f.seq for f in dec.feed(a)] == list(range(5))
    assert dec.feed(b) == [] and dec.counts.replayed == 5


def test_sim_main_refuses_a_boot_file_option_without_a_value(sim):
    tmp, _, _ = sim
    r = subprocess.run([micropython_command(), "-m", "ropenode.sim_main", "a", "b", "c", "--boot-file"],
                       env={"MICROPYPATH": str(FIRMWARE_DIR)}, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "usage" in r.stderr
