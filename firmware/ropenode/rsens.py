"""Sensor streams (.rsens, docs/data-formats.md) on the node, and the recording of one.

A site measures each cylinder's hydraulic compliance from a commissioning wind
recorded sample by sample (`ropemon fit-compliance`, docs/commissioning.md). The
node records one when armed: `ropemon record --port P --seconds S` writes the
decimal seconds into the flag file RECORD_FLAG; at its next boot the board HAL
removes the flag (a reset during the recording does not start it again) and,
alongside its normal work, appends the raw records of the next S seconds to
RECORD_FILE; `ropemon record --port P --fetch` copies the file off.

`Writer` keeps one preallocated block of records and writes it whole: no
allocation per sample. The words are written as the array holds them: every
target (ARM, Xtensa, RISC-V, x86) is little-endian, as the format is.
"""
import array
import struct

from micropython import const

MAGIC = b"RSNS"
HEADER = "<4sHHHH"        # magic, version 1, ropes, sample_hz, reserved 0
HEADER_LEN = const(12)
RECORD_FLAG = "record"      # relative to the node's root: / on a board
RECORD_FILE = "wind.rsens"
MAX_SECONDS = const(600)    # 10 min at 200 Hz and 4 ropes: 5.8 MB; flash runs out first
BLOCK = const(50)           # records per write: 1.2 KB at 4 ropes, four writes a second at 200 Hz


def armed_seconds(path=RECORD_FLAG):
    """The seconds the flag file asks for (1 .. MAX_SECONDS), else 0 (no flag, or not a number)."""
    try:
        with open(path) as f:
            s = int(f.read().strip())
    except (OSError, ValueError):
        return 0
    return s if 0 < s <= MAX_SECONDS else 0


class Writer:
    """Writes a .rsens stream of `samples` records to the open binary file `f`, then closes it."""

    def __init__(self, f, ropes, sample_hz, samples, block=BLOCK):
        self.f = f
        self.words = 2 * ropes + 4
        f.write(struct.pack(HEADER, MAGIC, 1, ropes, sample_hz, 0))
        self.buf = array.array("H", bytes(2 * block * self.words))
        self.end = len(self.buf)
        self.n = 0            # words in the block
        self.left = samples   # records still to write

    def add(self, rec):
        """Append one record (array('H') of 2N+4 words); False once all are written."""
        if self.left <= 0:
            return False
        buf = self.buf
        o = self.n
        for i in range(self.words):
            buf[o + i] = rec[i]
        o += self.words
        self.left -= 1
        if o == self.end:
            self.f.write(buf)
            o = 0
        self.n = o
        if self.left == 0:
            self.close()
            return False
        return True

    def close(self):
        """Write what the block holds and close the file (once the last record is in, or to stop early)."""
        f = self.f
        if f is None:
            return
        self.f = None
        self.left = 0
        try:
            if self.n:
                f.write(memoryview(self.buf)[:self.n])
        finally:  # closed even when that write fails (flash full)
            self.n = 0
            f.close()
