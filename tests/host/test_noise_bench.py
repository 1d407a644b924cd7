"""Radio noise is never data and never reaches the MAC check (CRC-32, checked first).

20,000 valid keyed frames damaged at random (bit flips, bursts, body bytes, pure
noise in a frame slot; host/ropemon/lab/bench/noise.py), each between its own
delimiters: with keys and without, through the streaming and the batch decoder,
none is taken as data, none is a MAC failure (a false LINK INTEGRITY alarm),
every one is counted as crc_fail or malformed. The 10**6 version, with the
figure for version 1's CRC-16 beside it, is `ropemon bench noise` (docs/protocol.md).
"""
from __future__ import annotations

from ropemon.lab.bench import noise

FRAMES = 20_000


def test_damaged_frames_are_never_data_and_never_reach_the_mac_check():
    f = noise.trial(FRAMES, seed=7)
    assert sum(f["per_mode"].values()) == FRAMES and min(f["per_mode"].values()) == FRAMES // 4
    for name in ("keyed", "unkeyed", "keyed_batch", "unkeyed_batch"):
        c = f[name]
        assert c["data"] == c["frames_ok"] == 0, (name, c)
        assert c["mac_fail"] == c["replayed"] == c["duplicate"] == 0, (name, c)
        assert c["crc_fail"] + c["malformed"] == FRAMES, (name, c)
        # every frame whose COBS and length survived was refused by the CRC-32 alone
        assert c["crc_fail"] == f["reached_crc_check"], (name, c)
    assert f["keyed"] == f["keyed_batch"] and f["unkeyed"] == f["unkeyed_batch"]
    assert f["reached_crc_check"] > FRAMES // 2  # the CRC is what is tested, not COBS


def test_the_damage_changes_every_frame_and_keeps_one_body_per_trial():
    data, v1_bodies, _ = noise.corrupted_wires(400, seed=3)
    bodies = [b for b in data.split(b"\x00") if b]
    assert len(bodies) == len(v1_bodies) == 400
    pool = {noise.cobs.encode(v2) for v2, _ in noise.frame_pool(noise.random.Random(3), 400)}
    assert not set(bodies) & pool


def test_version_1_check_takes_an_intact_version_1_frame():
    """The comparison's CRC-16 check is the old host's: it takes an undamaged old frame."""
    import random
    _, v1 = noise.frame_pool(random.Random(1), 1)[0]
    assert noise.version_1_takes(noise.cobs.encode(v1))
    assert not noise.version_1_takes(noise.cobs.encode(v1[:-1] + bytes([v1[-1] ^ 1])))
