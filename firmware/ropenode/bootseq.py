"""Frame sequence numbers that keep increasing across node resets.

    seq = (boot << SEQ_COUNT_BITS) | count       # 12-bit boot counter, 20-bit frame count

The node hands seq out as its 16-bit halves (low, high): seq itself reaches 2**32,
beyond a 32-bit MicroPython's small ints (+-2**30), and the frame packer takes halves.

The boot counter lives in a small file on the node's flash (decimal text),
read and incremented once per boot and rewritten only when the 20-bit frame
count wraps (2**20 frames = 29 h at 10 Hz): two flash writes a day at most,
never one per frame. Each write goes to a temp file renamed over the old one,
so a power cut leaves either the old or the new value. The host refuses any
frame whose seq is not newer than the last one it accepted (docs/protocol.md).

Without a path (the simulator's default) nothing is persisted and the boot
counter is given (0), so a replay of the same input gives the same bytes.
If the file cannot be written the node keeps running with the value in RAM:
after the next reset its seq repeats and the host says so (replayed frames).
"""
import os
import sys

from micropython import const

SEQ_COUNT_BITS = const(20)
COUNT_MASK = const(0xFFFFF)   # 2**20 - 1
BOOT_MASK = const(0xFFF)      # the boot counter wraps after 4096 boots (host: operator rebase)


def read_boot(path):
    """The boot counter last persisted in `path` (or its temp file), or -1 if none is readable."""
    for p in (path, path + ".tmp"):
        try:
            with open(p) as f:
                return int(f.read().strip()) & BOOT_MASK
        except (OSError, ValueError):
            pass
    return -1


def write_boot(path, boot):
    """Persist `boot` atomically (temp file + rename); False if the flash refused."""
    tmp = path + ".tmp"
    try:
        with open(tmp, "w") as f:
            f.write("%d\n" % boot)
        try:
            os.rename(tmp, path)
        except OSError:  # a filesystem whose rename does not replace (FAT): remove, then rename
            os.remove(path)
            os.rename(tmp, path)
        return True
    except OSError as e:
        print("ropenode: cannot persist the boot counter in", path, e, file=sys.stderr)
        return False


class FrameSeq:
    """Hands out the frame sequence numbers of one boot; `next()` once per frame."""

    def __init__(self, path=None, boot=0):
        """With `path`: boot = persisted value + 1 (0 for a missing file), written back now."""
        self.path = path
        if path is not None:
            boot = (read_boot(path) + 1) & BOOT_MASK
            write_boot(path, boot)
        self.boot = boot & BOOT_MASK
        self.count = 0

    def peek(self):
        """The seq the next frame will carry, as its 16-bit halves (low, high)."""
        return self.count & 0xFFFF, (self.boot << (SEQ_COUNT_BITS - 16)) | (self.count >> 16)

    def next(self):
        """This frame's seq (low, high); past 2**20 frames the boot counter is bumped (and persisted)."""
        seq = self.peek()
        if self.count == COUNT_MASK:
            self.count = 0
            self.boot = (self.boot + 1) & BOOT_MASK
            if self.path is not None:
                write_boot(self.path, self.boot)
        else:
            self.count += 1
        return seq
