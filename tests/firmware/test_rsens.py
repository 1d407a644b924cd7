"""The node's recording of a sensor stream (ropenode.rsens): the .rsens bytes it writes,
written in blocks without allocating per sample, and the flag that arms it.

Runs under CPython (pytest) and the real MicroPython (tests/run_micropython.py);
there an allocation inside heap_lock() raises MemoryError.
"""
import array
import os
import random
import struct
import sys

import micropython

from ropenode import rsens

ON_MICROPYTHON = sys.implementation.name == "micropython"


def _path(tag):
    """A fresh path in /tmp (no tempfile module in MicroPython)."""
    p = "/tmp/ropemon-rsens-%s-%s-%08x" % (tag, sys.implementation.name, random.getrandbits(32))
    try:
        os.remove(p)
    except OSError:
        pass
    return p


def _records(ropes, count):
    w = 2 * ropes + 4
    return [array.array("H", [(k * 131 + j * 7919) & 0xFFFF for j in range(w)]) for k in range(count)]


def _read(path, ropes):
    with open(path, "rb") as f:
        data = f.read()
    head = struct.unpack(rsens.HEADER, data[:rsens.HEADER_LEN])
    w = 2 * ropes + 4
    body = data[rsens.HEADER_LEN:]
    assert len(body) % (2 * w) == 0
    recs = [list(struct.unpack("<%dH" % w, body[o:o + 2 * w])) for o in range(0, len(body), 2 * w)]
    return head, recs


def test_a_recording_is_the_header_and_every_record_little_endian():
    for ropes, count, block in ((4, 123, 50), (1, 7, 50), (2, 100, 25)):
        path = _path("rec")
        recs = _records(ropes, count)
        wr = rsens.Writer(open(path, "wb"), ropes, 200, count, block)
        done = [wr.add(r) for r in recs]
        assert done == [True] * (count - 1) + [False]   # the last record closes the file
        assert wr.add(recs[0]) is False                  # nothing after the end
        head, got = _read(path, ropes)
        assert head == (b"RSNS", 1, ropes, 200, 0)
        assert got == [list(r) for r in recs]
        os.remove(path)


def test_closing_early_keeps_what_was_recorded():
    path = _path("early")
    recs = _records(4, 70)
    wr = rsens.Writer(open(path, "wb"), 4, 200, 1000)
    for r in recs:
        assert wr.add(r)
    wr.close()
    wr.close()  # twice: harmless
    assert _read(path, 4)[1] == [list(r) for r in recs]
    os.remove(path)


def test_recording_allocates_nothing_per_sample():
    """add() inside heap_lock, block writes to the file included (all but the last record,
    whose close() may allocate: once per recording)."""
    path = _path("alloc")
    count = 160
    recs = _records(4, count)
    wr = rsens.Writer(open(path, "wb"), 4, 200, count)
    k = 0
    micropython.heap_lock()
    try:
        while k < count - 1:
            wr.add(recs[k])
            k += 1
    except MemoryError:
        pass
    micropython.heap_unlock()
    assert k == count - 1, "record %d allocated" % k
    wr.add(recs[-1])
    assert len(_read(path, 4)[1]) == count
    os.remove(path)


def test_the_flag_arms_a_recording_of_1_to_600_seconds():
    path = _path("flag")
    assert rsens.armed_seconds(path) == 0  # no flag
    for text, want in (("120\n", 120), ("600", 600), ("0", 0), ("601", 0), ("-5", 0), ("two minutes", 0)):
        with open(path, "w") as f:
            f.write(text)
        assert rsens.armed_seconds(path) == want, text
    os.remove(path)
