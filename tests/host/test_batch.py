"""The numpy batch decoder gives exactly the streaming decoder's frames and counts."""
from __future__ import annotations

import os
import random

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from host_rig import KEYS, frame_set
from ropemon.station.batch import decode_bytes, decode_file
from ropemon.station.decoder import StreamDecoder

# ROPEMON_EXAMPLES=5000 for a deep run; the default keeps `make test` fast.
FAST = settings(max_examples=int(os.environ.get("ROPEMON_EXAMPLES", 100)), deadline=None,
                suppress_health_check=[HealthCheck.too_slow])


def stream(data: bytes, keys):
    d = StreamDecoder(keys)
    frames = d.feed(data)
    d.finish()
    return frames, d.counts


def check(data: bytes, keyed: bool) -> None:
    keys = KEYS if keyed else None
    want_frames, want_counts = stream(data, keys)
    got = decode_bytes(data, keys)
    assert got.counts == want_counts
    assert got.frames() == want_frames
    assert len(got) == len(want_frames)


@FAST
@given(st.binary(max_size=400), st.booleans())
def test_arbitrary_bytes(data, keyed):
    check(data, keyed)


@FAST
@given(st.integers(0, 2**32), st.integers(1, 60), st.booleans(), st.integers(0, 40), st.booleans(), st.booleans())
def test_damaged_duplicated_streams(seed, count, keyed, flips, dup, mixed):
    """`mixed`: frames of layout versions 2 and 3 interleaved (positions and stroke bits in 3's)."""
    rng = random.Random(seed)
    wires = [w for _, w in frame_set(seed, count, keyed, mixed=mixed)]
    if dup:
        wires += rng.sample(wires, min(5, len(wires)))  # replays when keyed
        rng.shuffle(wires)
    data = bytearray(b"".join(wires))
    for _ in range(flips):
        data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
    if rng.random() < 0.5:
        data += rng.randbytes(rng.randint(1, 90))
    check(bytes(data), keyed)


def test_columns_and_file(tmp_path):
    frames = frame_set(4, 50, False)
    p = tmp_path / "cap.bin"
    p.write_bytes(b"".join(w for _, w in frames))
    r = decode_file(p)
    want, _ = stream(p.read_bytes(), None)
    assert r.columns["seq"].tolist() == [f.seq for f in want]
    assert r.n_ropes.tolist() == [len(f.ropes) for f in want]
    i = next(i for i, f in enumerate(want) if len(f.ropes) == 4)
    assert r.ropes["mean_dan"][i].tolist() == [x.mean_dan for x in want[i].ropes]
    assert r.authenticated is None


def test_rewound_duplicate_and_replayed_counts_match_the_streaming_decoder():
    from ropemon.station.decoder import DUPLICATE_MEMORY, SEQ_COUNT_BITS
    from ropemon.station.protocol import encode_frame

    def w(seq, tension=1, node=1):
        return encode_frame(node=node, seq=seq, ropes=[(tension,) * 4], key=KEYS[node])[1]

    boot7 = [w((7 << SEQ_COUNT_BITS) | k) for k in range(DUPLICATE_MEMORY + 5)]
    retries = [boot7[-1], boot7[-2], w(3, node=2)]                   # duplicates: 2 (node 2's is new)
    older = [boot7[0], w((7 << SEQ_COUNT_BITS) | 60, tension=5)]      # replays of boot 7: 2
    wiped = [w(k) for k in range(3)]                                   # boot 0: rewound, 3
    data = b"".join(boot7 + retries + older + wiped + [w(3, node=2)])  # and node 2's retry
    check(data, True)
    c = decode_bytes(data, KEYS).counts
    assert (c.frames_ok, c.duplicate, c.replayed, c.rewound) == (len(boot7) + 1, 3, 5, 3)
