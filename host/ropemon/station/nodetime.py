"""A node's time unwrapped: its frames' u32 `time_ms` as milliseconds that keep counting.

`time_ms` is the node's time since boot modulo 2**32 (docs/protocol.md): it wraps after 49.7
days of uptime. The alarms, the trackers and replay protection only ever take differences
modulo 2**32 (`(t - last) % 2**32`, e.g. `equalizer.Continuity`), which a wrap does not
disturb; what lays frames out on a time axis (the trip report, the web face's trips, the CSV
export) needs one time that keeps counting through a wrap. `NodeClock` gives it, per node.

Within one boot counter value (seq >> 20) the node's time steps by the signed difference
modulo 2**32 (so a wrap adds 2**32, and a frame slightly out of order steps back a little).
The boot counter changes in two ways (docs/protocol.md, "Sequence numbers"):

- the node restarted: its time starts again from 0 (not a wrap), and so does this one;
- the 20-bit frame count ran over (every 2**20 frames, 29 h at 10 Hz) while the node kept
  running: boot + 1, count from 0, and the time follows on; so it does here, wraps counted.
  It is taken for a run-over when the boot counter is the next one, the frames between the
  two seqs are few (`ROLLOVER_FRAMES`) and the time moved forward by little (`ROLLOVER_GAP_MS`).

A restart is told apart without fail only by its time starting again; where a run-over is
taken for a restart (more than `ROLLOVER_FRAMES` frames lost across it), only the wraps counted
so far are lost: the value is still the node's time modulo 2**32.
"""
from __future__ import annotations

from collections.abc import Iterable

WRAP_MS = 1 << 32
SEQ_BOOT_SHIFT = 20            # seq = (boot << 20) | count (docs/protocol.md)
COUNT_MASK = (1 << SEQ_BOOT_SHIFT) - 1
BOOT_MASK = 0xFFF
ROLLOVER_FRAMES = 10_000       # frames lost across a count run-over, at most, for it to be one
ROLLOVER_GAP_MS = 3_600_000    # node time across a count run-over, at most


def _signed(d: int) -> int:
    """d modulo 2**32 as -2**31 .. 2**31 - 1."""
    return (d + (1 << 31)) % WRAP_MS - (1 << 31)


class NodeClock:
    """Unwraps the `time_ms` of each node's frames, taken in the order they arrived (module
    docstring). `ms(frame)` (or `ms_of(node, seq, time_ms)`) returns the node's time in ms,
    counting the wraps since the first frame this clock saw of that node's current run."""

    __slots__ = ("_last",)

    def __init__(self) -> None:
        self._last: dict[int, tuple[int, int, int]] = {}   # node -> (seq, time_ms, unwrapped ms)

    def ms_of(self, node: int, seq: int, time_ms: int) -> int:
        last = self._last.get(node)
        if last is None:
            out = time_ms
        else:
            seq0, raw0, out0 = last
            boot0, boot = seq0 >> SEQ_BOOT_SHIFT, seq >> SEQ_BOOT_SHIFT
            if boot == boot0:
                out = out0 + _signed(time_ms - raw0)
            else:
                forward = (time_ms - raw0) % WRAP_MS
                frames = (COUNT_MASK - (seq0 & COUNT_MASK)) + (seq & COUNT_MASK) + 1
                if (boot == (boot0 + 1) & BOOT_MASK and frames <= ROLLOVER_FRAMES
                        and forward <= ROLLOVER_GAP_MS):
                    out = out0 + forward          # the count ran over: the same run goes on
                else:
                    out = time_ms                 # a restart: the node's time starts again
        self._last[node] = (seq, time_ms, out)
        return out

    def ms(self, frame) -> int:
        """The unwrapped time (ms) of a `ropemon.station.protocol.Frame` (node, seq, time_ms)."""
        return self.ms_of(frame.node, frame.seq, frame.time_ms)


def unwrapped_ms(frames: Iterable) -> list[int]:
    """Each frame's unwrapped node time (ms), the frames taken in the order given (arrival)."""
    clock = NodeClock()
    return [clock.ms(f) for f in frames]
