"""Merge frames from several receivers into one stream per node, by sequence number.

Both receivers may hear the same frame: the first copy is new, later copies are
duplicates (same node, seq and bytes). A node counts seq from 0 after a reset: an
earlier seq with other contents, or one far behind, starts a new sequence (`restarts`). Sequence gaps count frames no receiver delivered ("lost"); a late
frame that fills a gap is new and un-counts its loss. Link quality per receiver
is the share of the node's sent frames (received by anyone + lost) that this
receiver delivered, overall and by cage depth bin (a lost frame is attributed to
the depth of the frame that revealed the gap: depth is only known from frames).
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

from ropemon.station.protocol import Frame

#: Sequence numbers remembered per node for duplicate detection.
SEEN_WINDOW = 4096
#: A frame this far behind the newest seq means the node restarted its counter.
RESTART_BACK = SEEN_WINDOW


@dataclass
class _DepthBin:
    sent: int = 0  # unique frames + frames lost here
    delivered: dict[str, int] = field(default_factory=dict)


@dataclass
class _NodeState:
    top: int = -1
    low: int = -1  # lowest seq of the current sequence (frames may arrive late, out of order)
    seen: "OrderedDict[int, tuple[Frame, set[str]]]" = field(default_factory=OrderedDict)
    unique: int = 0
    duplicates: int = 0
    conflicts: int = 0  # same seq, different bytes (only possible without MAC)
    lost: int = 0
    restarts: int = 0
    delivered: dict[str, int] = field(default_factory=dict)
    bins: dict[int, _DepthBin] = field(default_factory=dict)
    missing: dict[int, int] = field(default_factory=dict)  # lost seq -> depth bin charged


class Merger:
    """`add(receiver, frame) -> True` for a new frame, False for a duplicate."""

    def __init__(self, depth_bin_m: float = 100.0):
        self.depth_bin_mm = int(depth_bin_m * 1000)
        self._nodes: dict[int, _NodeState] = {}
        self.receivers: list[str] = []

    def add(self, receiver: str, frame: Frame) -> bool:
        if receiver not in self.receivers:
            self.receivers.append(receiver)
        st = self._nodes.get(frame.node)
        if st is None:
            st = self._nodes[frame.node] = _NodeState()
        seq = frame.seq
        prev = st.seen.get(seq)
        if st.top >= 0 and (seq < st.top - RESTART_BACK
                            or (prev is not None and seq < st.top and not prev[0].same_payload(frame))):
            # Too old to be late, or an earlier seq with other contents: the node reset and
            # counts from 0 again. Keep the totals, start a new sequence.
            st.restarts += 1
            st.top = st.low = -1
            st.seen.clear()
            st.missing.clear()
            prev = None
        key = frame.depth_mm // self.depth_bin_mm
        b = self._bin(st, key)
        if prev is not None:
            st.duplicates += 1
            if not prev[0].same_payload(frame):
                st.conflicts += 1  # same newest seq, other bytes: corruption that passed the CRC
            if receiver not in prev[1]:
                prev[1].add(receiver)
                self._delivered(st, b, receiver)
            return False
        self._delivered(st, b, receiver)
        if st.top >= 0 and seq < st.low:
            # Older than the first frame seen (another receiver lags): seqs between are lost.
            gap = st.low - seq - 1
            st.lost += gap
            b.sent += gap
            for s in range(seq + 1, min(st.low, seq + 1 + SEEN_WINDOW)):
                st.missing[s] = key
            st.low = seq
        elif st.top >= 0 and seq < st.top:
            charged = st.missing.pop(seq, None)
            if charged is not None:  # a late frame filling a gap: no longer lost
                st.lost -= 1
                st.bins[charged].sent -= 1
        elif st.top >= 0 and seq > st.top + 1:
            gap = seq - st.top - 1
            st.lost += gap
            b.sent += gap
            for s in range(max(st.top + 1, seq - SEEN_WINDOW), seq):
                st.missing[s] = key
        if seq > st.top:
            st.top = seq
        if st.low < 0:
            st.low = seq
        st.seen[seq] = (frame, {receiver})
        while len(st.seen) > SEEN_WINDOW:
            st.seen.popitem(last=False)
        if len(st.missing) > SEEN_WINDOW:
            floor = st.top - SEEN_WINDOW
            st.missing = {s: k for s, k in st.missing.items() if s > floor}
        st.unique += 1
        b.sent += 1
        return True

    def has(self, node: int, seq: int) -> bool:
        """True if a frame (node, seq) of the current sequence is remembered (a copy would be a duplicate)."""
        st = self._nodes.get(node)
        return st is not None and seq in st.seen

    @staticmethod
    def _delivered(st: _NodeState, b: _DepthBin, receiver: str) -> None:
        st.delivered[receiver] = st.delivered.get(receiver, 0) + 1
        b.delivered[receiver] = b.delivered.get(receiver, 0) + 1

    @staticmethod
    def _bin(st: _NodeState, k: int) -> _DepthBin:
        b = st.bins.get(k)
        if b is None:
            b = st.bins[k] = _DepthBin()
        return b

    def stats(self) -> dict:
        """Per node: unique, duplicates, lost, conflicts, restarts, receiver shares overall and by depth."""
        out = {}
        for node, st in sorted(self._nodes.items()):
            sent = st.unique + st.lost
            bins = []
            for k in sorted(st.bins):
                b = st.bins[k]
                bins.append({
                    "depth_from_m": k * self.depth_bin_mm / 1000,
                    "depth_to_m": (k + 1) * self.depth_bin_mm / 1000,
                    "sent": b.sent,
                    "share": {r: (b.delivered.get(r, 0) / b.sent if b.sent > 0 else None)
                              for r in self.receivers},
                })
            out[node] = {
                "unique": st.unique,
                "duplicates": st.duplicates,
                "lost": st.lost,
                "conflicts": st.conflicts,
                "restarts": st.restarts,
                "last_seq": st.top,
                "receivers": {
                    r: {"delivered": st.delivered.get(r, 0),
                        "share": st.delivered.get(r, 0) / sent if sent else None}
                    for r in self.receivers
                },
                "by_depth": bins,
            }
        return out
