"""Property tests of the streaming decoder and the merge over damaged, duplicated, reordered streams."""
from __future__ import annotations

import os
import random

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from host_rig import KEYS, expected, frame_set
from ropemon.station.decoder import StreamDecoder
from ropemon.station.merge import Merger
from ropemon.station.protocol import L, MAX_BODY_LEN

# ROPEMON_EXAMPLES=5000 for a deep run; the default keeps `make test` fast.
FAST = settings(max_examples=int(os.environ.get("ROPEMON_EXAMPLES", 400)), deadline=None,
                suppress_health_check=[HealthCheck.too_slow])


def feed_chunked(dec: StreamDecoder, data: bytes, cuts: list[int]) -> list:
    out = []
    prev = 0
    for c in sorted(set(x % (len(data) + 1) for x in cuts)) + [len(data)]:
        out += dec.feed(data[prev:c])
        prev = c
    return out


@FAST
@given(st.binary(max_size=600), st.lists(st.integers(0, 10**6), max_size=20), st.booleans())
def test_arbitrary_bytes_never_raise_and_chunking_does_not_matter(data, cuts, keyed):
    whole = StreamDecoder(KEYS if keyed else None)
    a = whole.feed(data)
    chunked = StreamDecoder(KEYS if keyed else None)
    b = feed_chunked(chunked, data, cuts)
    assert a == b
    assert whole.counts == chunked.counts
    assert chunked.pending <= MAX_BODY_LEN
    # Every byte is accounted for: in a good frame, an idle delimiter, discarded, or still pending.
    c = whole.counts
    good = sum(L.frame_len(len(f.ropes), f.version) + 2 for f in a)  # COBS adds 1, delimiter 1 (< 254 B)
    idle = data.count(b"\x00") - (c.frames_ok + c.crc_fail + c.malformed + c.mac_fail + c.replayed
                                       + c.duplicate)
    assert idle >= 0
    assert good + idle + c.bytes_discarded + whole.pending == len(data)


@st.composite
def damaged_streams(draw):
    """Two receivers' streams of the same frames, each with loss, damage, junk, duplicates, reordering;
    the frames of layout version 3 only, or of versions 2 and 3 interleaved (nodes not yet upgraded)."""
    keyed = draw(st.booleans())
    frames = frame_set(draw(st.integers(0, 2**32)), draw(st.integers(1, 25)), keyed, mixed=draw(st.booleans()))
    rng = random.Random(draw(st.integers(0, 2**32)))
    streams = []
    for _ in range(2):
        segs = []  # (frame index or None for junk, bytes, intact?)
        order = list(range(len(frames)))
        for _ in range(rng.randint(0, 3)):  # local reordering
            i = rng.randrange(len(order))
            j = min(len(order) - 1, i + rng.randint(1, 3))
            order[i], order[j] = order[j], order[i]
        for i in order:
            r = rng.random()
            if r < 0.15:
                continue  # lost on the radio
            wire = frames[i][1]
            if r < 0.35:
                b = bytearray(wire)
                for _ in range(rng.randint(1, 3)):
                    b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
                # two flips of the same bit restore the frame: then it is intact, not damaged
                segs.append((i, bytes(b), bytes(b) == wire))
            elif r < 0.45:
                segs.append((i, wire[: rng.randrange(1, len(wire))], False))  # truncated
            else:
                segs.append((i, wire, True))
                if rng.random() < 0.1:
                    segs.append((i, wire, True))  # duplicated by this receiver
            if rng.random() < 0.15:
                segs.append((None, rng.randbytes(rng.randint(1, 80)), False))
        streams.append(segs)
    cuts = draw(st.lists(st.integers(0, 10**6), max_size=30))
    return keyed, frames, streams, cuts


def recoverable(segs, sent, wires, strict: bool) -> set[int]:
    """Frames whose whole wire bytes (0x00 + COBS + 0x00) are in the stream where their
    segment starts: intact, or cut just before the closing 0x00 and followed by a
    segment that starts with one (the next frame's leading delimiter completes it).
    With `strict` (keys: the default replay check) only those newer than every frame
    of their node recovered before them in this stream: a receiver delivers in order,
    so within one stream a frame behind a newer one is a replay."""
    data = b"".join(b for _, b, _ in segs)
    out = set()
    top: dict[int, int] = {}
    off = 0
    for i, b, _ in segs:
        if i is not None:
            w = wires[i]
            whole = data[off:off + len(w)] == w and (off == 0 or data[off - 1] == 0 or w[0] == 0)
            f = sent[i]
            if whole and (not strict or f.seq > top.get(f.node, -1)):
                out.add(i)
                top[f.node] = f.seq
        off += len(b)
    return out


@FAST
@given(damaged_streams())
def test_damaged_streams_emit_only_intact_frames_each_once_after_merge(case):
    keyed, frames, streams, cuts = case
    sent = [expected(raw, keyed) for raw, _ in frames]
    by_seq = {(f.node, f.seq): f for f in sent}
    merger = Merger()
    new = []
    must = set()
    for name, segs in zip(("pithead", "midshaft"), streams):
        dec = StreamDecoder(KEYS if keyed else None)
        data = b"".join(b for _, b, _ in segs)
        got = feed_chunked(dec, data, cuts)
        for f in got:
            # No corrupted frame: every emitted frame is exactly one that was sent.
            assert by_seq.get((f.node, f.seq)) == f
            if keyed:
                assert f.authenticated is True
            else:
                assert f.authenticated is None
            if merger.add(name, f):
                new.append((f.node, f.seq))
        wires = [w for _, w in frames]
        must |= {(sent[i].node, sent[i].seq) for i in recoverable(segs, sent, wires, keyed)}
        if keyed:  # each intact frame behind a newer one of its node was dropped and counted
            stale = recoverable(segs, sent, wires, False) - recoverable(segs, sent, wires, True)
            assert dec.counts.replayed >= len(stale)
            assert not {(sent[i].node, sent[i].seq) for i in stale} & {(f.node, f.seq) for f in got}
    assert len(new) == len(set(new)), "a frame was delivered as new twice"
    assert must <= set(new), "an intact frame was not recovered"


def test_garbage_without_delimiters_cannot_grow_memory():
    dec = StreamDecoder()
    rng = random.Random(1)
    for _ in range(200):
        dec.feed(bytes(rng.randint(1, 255) for _ in range(97)))
        assert dec.pending <= MAX_BODY_LEN
    assert dec.feed(b"\x00") == []
    assert dec.counts.malformed == 1
    assert dec.counts.bytes_discarded == 200 * 97 + 1
    _, wire = frame_set(3, 1, False)[0]
    assert len(dec.feed(wire)) == 1  # resynchronised at the delimiter
