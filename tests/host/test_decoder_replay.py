"""Strict replay protection: seq monotonic across node resets (boot counter), refused rewinds,
operator acceptance, exact copies (radio retries) told from replays, and the firmware's boot
counter end to end under `micropython`."""
from __future__ import annotations

import json
import struct
import subprocess
from pathlib import Path

import pytest

from host_rig import KEYS
from ropemon.station.alarms import AlarmEngine, AlarmSettings
from ropemon.station.alarmstate import Timing
from ropemon.station.decoder import DUPLICATE_MEMORY, SEQ_COUNT_BITS, ReplayGuard, StreamDecoder
from ropemon.firmware import FIRMWARE_DIR
from ropemon.station.protocol import encode_frame
from ropemon.lab.virtualnode import micropython_command


def wires(node: int, seqs, key: bytes | None = None, tension: int = 1) -> list[bytes]:
    """Wire frames; frames with another `tension` have the same seq but other bytes."""
    return [encode_frame(node=node, seq=s, ropes=[(tension,) * 4], key=KEYS[node] if key is None else key)[1]
            for s in seqs]


def boot(b: int, k: int) -> int:
    return (b << SEQ_COUNT_BITS) | k


def test_strict_by_default_with_keys():
    dec = StreamDecoder(KEYS)
    w = wires(1, range(10, 20))
    assert [f.seq for f in dec.feed(b"".join(w))] == list(range(10, 20))
    # Not newer than the last accepted and not a copy of it: dropped, even one step back
    # (no reordering window).
    other = wires(1, range(10, 20), tension=2)
    assert dec.feed(other[-2] + other[-1] + other[0]) == []
    assert dec.counts.replayed == 3 and dec.counts.rewound == 0 and dec.replay.rewound == {}
    assert dec.counts.duplicate == 0
    assert [f.seq for f in dec.feed(b"".join(wires(1, [25])))] == [25]  # a gap is fine
    assert [f.seq for f in dec.feed(b"".join(wires(2, [0])))] == [0]  # nodes are independent


def test_a_node_reset_continues_and_a_recorded_earlier_boot_is_refused():
    dec = StreamDecoder(KEYS)
    boot0 = wires(1, [boot(0, k) for k in range(5)])
    boot1 = wires(1, [boot(1, k) for k in range(DUPLICATE_MEMORY)])
    # the reset needs no special case
    assert len(dec.feed(b"".join(boot0 + boot1))) == 5 + DUPLICATE_MEMORY
    assert dec.feed(b"".join(boot0)) == []              # replaying the recorded first boot
    assert dec.counts.replayed == 5 and dec.counts.rewound == 5
    assert dec.replay.rewound == {1: (1, 0)}
    assert "node 1 REFUSED: its boot counter went back from 1 to 0" in dec.summary()
    assert "an operator must accept node 1" in dec.summary()
    nxt = boot(1, DUPLICATE_MEMORY)
    assert [f.seq for f in dec.feed(boot1[-1] + b"".join(wires(1, [nxt])))] == [nxt]
    assert dec.counts.replayed == 5 and dec.counts.duplicate == 1  # boot1[-1] again: a retry
    # the node is fine again
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
    # The same decision given up front: it waits for the rewind, through normal frames.
    pre = StreamDecoder(KEYS, accept_rewound=[1])
    assert len(pre.feed(b"".join(wires(1, [boot(7, 0), boot(7, 1), boot(2, 0), boot(2, 1)])))) == 4
    assert pre.counts.replayed == 0
    assert pre.feed(wiped[0]) == [] and pre.counts.rewound == 1  # once only
    pre2 = StreamDecoder(KEYS)
    pre2.feed(b"".join(wires(1, [boot(7, 0)])))
    pre2.replay.accept_rewound(1)
    assert len(pre2.feed(b"".join(wiped[:2]))) == 2


def test_a_forged_frame_cannot_use_the_operator_acceptance():
    dec = StreamDecoder(KEYS, accept_rewound=[1])
    assert dec.feed(b"".join(wires(1, [5], key=bytes(16)))) == []  # wrong key: MAC fails first
    assert dec.counts.mac_fail == 1
    # the acceptance is still there for the real node's rewind
    assert len(dec.feed(b"".join(wires(1, [boot(3, 0), boot(2, 0)])))) == 2


def test_an_acceptance_covers_only_a_rewind_and_lapses_when_the_node_comes_back():
    dec = StreamDecoder(KEYS, accept_rewound=[1])
    w = wires(1, [boot(4, k) for k in range(3)])
    dec.feed(w[0] + w[2])
    other = wires(1, [boot(4, 1)], tension=7)[0]
    assert dec.feed(other) == [] and dec.counts.replayed == 1  # same boot, older: still a replay
    assert dec.feed(wires(1, [boot(3, 9)])[0]) != []          # the rewind it was given for
    # Accepted while refused, but the node's own newer frames come first: the acceptance lapses.
    dec = StreamDecoder(KEYS)
    dec.feed(b"".join(wires(1, [boot(5, 0), boot(2, 0)])))
    assert dec.replay.rewound == {1: (5, 2)}
    dec.replay.accept_rewound(1)
    assert len(dec.feed(b"".join(wires(1, [boot(5, 1)])))) == 1
    assert dec.feed(b"".join(wires(1, [boot(2, 1)]))) == [] and dec.counts.rewound == 2


def test_refusals_raise_the_link_integrity_alarm():
    eng = AlarmEngine(AlarmSettings(link_timing=Timing(raise_after_s=0, clear_after_s=10, min_frames=1)))
    dec = StreamDecoder(KEYS)
    dec.feed(b"".join(wires(1, [boot(2, 0)])))
    assert eng.update_link("pithead", dec.counts.mac_fail, dec.counts.replayed, 1.0) == []
    dec.feed(b"".join(wires(1, [boot(1, 0)])))
    ev = eng.update_link("pithead", dec.counts.mac_fail, dec.counts.replayed, 2.0)
    assert [(e.action, e.alarm) for e in ev] == [("raise", "link_integrity:pithead")]


def test_without_keys_nothing_is_refused_and_with_them_a_seq_restart_is():
    plain = StreamDecoder()
    w = wires(1, [5, 5, 1])
    assert [f.seq for f in plain.feed(b"".join(w))] == [5, 5, 1]
    assert "NOT checked" in plain.summary()
    # There is no mode that takes a seq restarting at 0 as a node reset: the node's boot
    # counter keeps seq increasing across resets, so a restart is a replay.
    guard = ReplayGuard()
    assert guard.accept(1, 500) and not guard.accept(1, 0) and not guard.accept(1, 499)
    import pytest
    with pytest.raises(TypeError):
        ReplayGuard(accept_restarts=True)  # the legacy mode is gone, not silently ignored


def test_exact_copies_are_duplicates_and_raise_no_alarm():
    eng = AlarmEngine(AlarmSettings(link_timing=Timing(raise_after_s=0, clear_after_s=10, min_frames=1)))
    dec = StreamDecoder(KEYS)
    w = wires(1, range(100, 100 + DUPLICATE_MEMORY + 10))
    retried = []
    for x in w:
        retried += [x, x]  # every frame retried by the radio
    got = dec.feed(b"".join(retried))
    assert [f.seq for f in got] == list(range(100, 100 + DUPLICATE_MEMORY + 10))
    c = dec.counts
    assert (c.duplicate, c.replayed, c.rewound) == (len(w), 0, 0)
    # the copies, dropped: body and closing 0x00 (the leading 0x00 is an idle delimiter)
    assert c.bytes_discarded == sum(len(x) - 1 for x in w)
    assert eng.update_link("pithead", c.mac_fail, c.replayed, 1.0) == []
    # The newest DUPLICATE_MEMORY frames are remembered: copies of them are still duplicates ...
    assert dec.feed(w[-DUPLICATE_MEMORY]) == [] and dec.counts.duplicate == len(w) + 1
    # ... an older copy is a replay (memory is bounded), and so is another frame with a
    # remembered seq: same seq, other bytes, valid MAC.
    assert dec.feed(w[-DUPLICATE_MEMORY - 1]) == [] and dec.counts.replayed == 1
    assert dec.feed(wires(1, [100 + len(w) - 1], tension=9)[0]) == [] and dec.counts.replayed == 2
    assert dec.counts.duplicate == len(w) + 1
    ev = eng.update_link("pithead", dec.counts.mac_fail, dec.counts.replayed, 2.0)
    assert [(e.action, e.alarm) for e in ev] == [("raise", "link_integrity:pithead")]
    assert "duplicate=%d" % (len(w) + 1) in dec.summary()


def test_copies_are_per_node():
    dec = StreamDecoder(KEYS)
    a, b = wires(1, [5])[0], wires(2, [5])[0]
    assert len(dec.feed(a + b)) == 2
    assert dec.feed(b + a) == [] and dec.counts.duplicate == 2


def test_a_retry_does_not_use_up_the_operator_acceptance():
    dec = StreamDecoder(KEYS)
    seven = wires(1, [boot(7, k) for k in range(3)])
    dec.feed(b"".join(seven))
    dec.replay.accept_rewound(1)
    assert dec.feed(seven[1]) == [] and dec.counts.duplicate == 1  # a late retry of boot 7
    wiped = wires(1, [boot(0, 0), boot(0, 1)])
    assert [f.seq for f in dec.feed(b"".join(wiped))] == [boot(0, 0), boot(0, 1)]
    assert dec.counts.replayed == 0 and dec.counts.rewound == 0


def test_guard_memory_is_bounded():
    g = ReplayGuard(memory=4)
    raw = [bytes([i]) * 8 for i in range(10)]
    for i, r in enumerate(raw):
        assert g.check(1, i, r) is ReplayGuard.ACCEPTED
    assert len(g._recent[1]) == 4
    assert g.check(1, 6, raw[6]) is ReplayGuard.DUPLICATE
    assert g.check(1, 5, raw[5]) is ReplayGuard.REPLAYED
    assert g.check(1, 9, None) is ReplayGuard.REPLAYED  # no bytes given: no copy check
    with pytest.raises(ValueError):
        ReplayGuard(memory=0)


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
    keys = {doc["node"]["node_id"]: bytes(doc["node"]["key"])}

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
    # To this host the first boot's frames are exact copies of frames it just took: dropped, no alarm.
    assert dec.feed(runs[0]) == [] and dec.counts.duplicate == 5 and dec.counts.replayed == 0
    # To a host that did not take them (it came up at the third boot) they are a replayed earlier boot.
    late = StreamDecoder(keys)
    assert len(late.feed(runs[2])) == 5
    assert late.feed(runs[0]) == [] and late.counts.replayed == 5 and late.counts.rewound == 5


def test_sim_without_a_boot_file_is_deterministic_and_a_rerun_is_a_replay(sim):
    tmp, keys, run = sim
    a, b = run("a.bin"), run("b.bin")
    assert a == b
    dec = StreamDecoder(keys)
    assert [f.seq for f in dec.feed(a)] == list(range(5))
    assert dec.feed(b) == [] and dec.counts.duplicate == 5  # the same bytes just taken: copies
    # Once the host has taken DUPLICATE_MEMORY newer frames, the rerun is a replay.
    ((node, key),) = keys.items()
    newer = wires(node, range(5, 5 + DUPLICATE_MEMORY), key=key)
    assert len(dec.feed(b"".join(newer))) == DUPLICATE_MEMORY
    assert dec.feed(b) == [] and dec.counts.replayed == 5 and dec.counts.duplicate == 5


def test_sim_main_refuses_a_boot_file_option_without_a_value(sim):
    tmp, _, _ = sim
    r = subprocess.run([micropython_command(), "-m", "ropenode.sim_main", "a", "b", "c", "--boot-file"],
                       env={"MICROPYPATH": str(FIRMWARE_DIR)}, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "usage" in r.stderr
