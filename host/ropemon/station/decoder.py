"""Streaming frame decoder: bytes in any chunking -> checked `Frame`s, with counts.

Frames are COBS bodies between 0x00 delimiters (the node sends one before and
one after each frame). The decoder splits on 0x00, so it resynchronises at the
next delimiter after any damage; the leading one ends any junk before a frame.
The CRC-32 is checked before anything else in the frame (the MAC too), so radio
noise is counted as `crc_fail` and never reaches the MAC check. Layout versions 2
and 3 (L.VERSIONS) are decoded side by side, the version byte picking the layout
once the CRC holds; an intact frame of another layout version is `malformed`, and
named in the summary (`versions`), as is one whose length is not its version's.
A body longer than the longest valid frame is skipped without being buffered
(garbage without delimiters cannot grow memory). Each rejected body is counted once by cause and
its bytes, delimiter included, are added to `bytes_discarded`; idle delimiters
(empty bodies) are neither frames nor discarded bytes. The result does not
depend on how the input is chunked.

With node keys, a frame whose MAC fails, or whose sequence number is not newer
than the last one accepted from its node, is dropped and counted (`mac_fail`,
`replayed`), except an exact copy of one of the last DUPLICATE_MEMORY frames
accepted from its node (a radio retry): that is dropped as `duplicate`, not an
attack, and raises no alarm. The node keeps its seq increasing across resets (boot counter in
the top bits, docs/protocol.md), so a node whose boot counter went backwards
(flash wiped, counter wrapped) is refused too, and listed in `rewound`, until
an operator accepts it (`accept_rewound`). Without keys every frame has
authenticated=None and `authenticity_checked` is False.

A host that restarts continues where it stopped: `ReplayGuard.seed` takes the
last seq and the last frames accepted per node (from the log: `Store.last_seqs`,
`Store.recent_frames`), so frames logged before the restart are still replays or
duplicates after it.
"""
from __future__ import annotations

import binascii
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass

from cobs import cobs

from ropemon.station import protocol as P
from ropemon.firmware import node_module

L = P.L

#: Accepted frames remembered per node to tell an exact copy (radio retry) from a replay.
#: A retry follows its original within milliseconds; 64 frames is 6.4 s at 10 frames/s.
DUPLICATE_MEMORY = 64
#: seq = (boot << SEQ_COUNT_BITS) | frame count (firmware/ropenode/bootseq.py).
SEQ_COUNT_BITS: int = node_module("bootseq").SEQ_COUNT_BITS


@dataclass(slots=True)
class DecodeCounts:
    frames_ok: int = 0
    crc_fail: int = 0
    malformed: int = 0
    mac_fail: int = 0
    replayed: int = 0
    bytes_discarded: int = 0
    rewound: int = 0   # of `replayed`: frames of an older boot than the newest accepted one
    duplicate: int = 0  # exact copies of a recently accepted frame (radio retry): dropped, not an attack

    def as_dict(self) -> dict[str, int]:
        return asdict(self)

    def add(self, other: "DecodeCounts") -> None:
        for k, v in asdict(other).items():
            setattr(self, k, getattr(self, k) + v)


class ReplayGuard:
    """Per-node anti-replay check over the 32-bit sequence number.

    A frame is accepted only if its seq is newer than the
    last accepted one of its node. The node's seq never goes back, across resets
    too: seq = (boot << SEQ_COUNT_BITS) | count, with the boot counter persisted
    on its flash. A frame of an older boot than the newest accepted is refused
    and the node is listed in `rewound` {node: (newest boot, that frame's boot)}:
    either a recording of an earlier boot is being replayed, or the node really
    lost its boot counter (flash wiped or replaced, or 4096 boots wrapped it).
    Only an operator can tell: `accept_rewound(node)` (or `accept_rewound` at
    construction) takes that node's next authenticated frame of an older boot as
    its new baseline, once; a replay within the same boot stays refused. An
    acceptance given while the node was refused is dropped if the node's newer
    frames come back first (the rewind was a replay, not the node).

    A refused frame whose bytes equal one of the last `memory` frames accepted
    from its node is a `DUPLICATE` (a radio retry), not a replay; a retry does
    not use up an operator's acceptance.

    Each new baseline taken on an acceptance is appended to `rebased` as
    (node, its seq, the previous newest seq), for the log: a restarted host
    resumes from it (`seed`).
    """

    ACCEPTED, DUPLICATE, REPLAYED, REWOUND = "accepted", "duplicate", "replayed", "rewound"

    def __init__(self, accept_rewound: Iterable[int] = (), memory: int = DUPLICATE_MEMORY):
        if memory < 1:
            raise ValueError("memory must be at least 1 frame")
        self.memory = memory
        self._recent: dict[int, dict[int, bytes]] = {}  # node -> {seq: frame bytes}, oldest first
        self.rewound: dict[int, tuple[int, int]] = {}
        self._rebase: set[int] = set(accept_rewound)
        self._top: dict[int, int] = {}
        self.rebased: list[tuple[int, int, int]] = []  # (node, new baseline seq, previous newest seq)

    def accept_rewound(self, node: int) -> None:
        """Operator decision: take `node`'s next frame of an older boot as its new baseline."""
        self._rebase.add(node)

    def seed(self, last: Mapping[int, int], recent: Mapping[int, Iterable[P.Frame]] | None = None) -> None:
        """Continue from an earlier run (a host restart): `last` {node: newest seq
        accepted}, `recent` {node: the last frames accepted from it, oldest first}.

        Afterwards a frame of that node at or below that seq is refused as if this
        guard had accepted it itself (REPLAYED, or REWOUND for an older boot), and an
        exact copy of one of the `recent` frames (the last `memory`) is a DUPLICATE.
        A node this guard has already accepted frames from keeps its own state.
        """
        recent = recent or {}
        for node, seq in last.items():
            if not 0 <= seq < 1 << 32:
                raise ValueError(f"seed: node {node}: seq {seq} is not a 32-bit sequence number")
            if node in self._top:
                continue
            self._top[node] = seq
            for f in recent.get(node, ()):
                if f.node != node:
                    raise ValueError(f"seed: recent frames of node {node} include one of node {f.node}")
                if f.seq <= seq:
                    self._remember(node, f.seq, frame_bytes(f))

    def accept(self, node: int, seq: int) -> bool:
        """True and remembered if (node, seq) is fresh; False if refused (a replay)."""
        return self.check(node, seq) is self.ACCEPTED

    def check(self, node: int, seq: int, frame: bytes | None = None) -> str:
        """ACCEPTED (and remembered), DUPLICATE, REPLAYED or REWOUND (a replayed
        frame of an older boot). `frame`: the frame's bytes, to recognise exact
        copies; None: no duplicate check."""
        top = self._top.get(node)
        if top is None or seq > top:
            if self.rewound.pop(node, None) is not None:
                # The refusal ended by itself (the node's own newer frames): an acceptance
                # given for it must not stay pending for a later replay to use.
                self._rebase.discard(node)
            return self._take(node, seq, frame)
        if self._is_copy(node, seq, frame):
            return self.DUPLICATE
        boot, top_boot = seq >> SEQ_COUNT_BITS, top >> SEQ_COUNT_BITS
        if boot >= top_boot:
            return self.REPLAYED  # same boot, older frame: an acceptance does not cover it
        if node in self._rebase:
            self._rebase.discard(node)
            self.rewound.pop(node, None)
            self._recent.pop(node, None)  # a new baseline: the old boot's frames are not copies of it
            self.rebased.append((node, seq, top))
            return self._take(node, seq, frame)
        self.rewound[node] = (top_boot, boot)
        return self.REWOUND

    def _take(self, node: int, seq: int, frame: bytes | None) -> str:
        self._top[node] = seq
        return self._remember(node, seq, frame)

    def _remember(self, node: int, seq: int, frame: bytes | None) -> str:
        if frame is not None:
            recent = self._recent.setdefault(node, {})
            recent.pop(seq, None)
            recent[seq] = frame
            if len(recent) > self.memory:
                del recent[next(iter(recent))]
        return self.ACCEPTED

    def _is_copy(self, node: int, seq: int, frame: bytes | None) -> bool:
        return frame is not None and self._recent.get(node, {}).get(seq) == frame


def frame_bytes(f: P.Frame) -> bytes:
    """The raw bytes (COBS removed) a decoded or logged frame came in: its fields,
    its MAC as received, and the CRC-32 over them. What `ReplayGuard` compares copies by."""
    body = P.HEADER.pack(f.version, f.kind, f.node, f.fault_mask, f.seq, f.time_ms, f.status)
    if f.version == 2:
        body += b"".join(P.V2_ROPE.pack(*r[:4]) for r in f.ropes)
        body += P.V2_TAIL.pack(f.depth_mm, f.speed_mm_s, f.battery_mv, f.oil_temp_cc) + f.mac
    else:
        body += b"".join(P.ROPE.pack(*r) for r in f.ropes)
        body += P.TAIL.pack(f.depth_mm, f.speed_mm_s, f.battery_mv, f.oil_temp_cc, f.stroke_mask) + f.mac
    return body + P.CRC.pack(P.crc32(body))


class StreamDecoder:
    """Feed bytes, get frames. `keys`: node -> HMAC key; None or {} = not checked.

    `accept_rewound`: see ReplayGuard."""

    def __init__(self, keys: dict[int, bytes] | None = None, max_frame: int = P.MAX_BODY_LEN + 1,
                 accept_rewound: Iterable[int] = ()):
        if max_frame < 2:
            raise ValueError("max_frame must be at least 2 bytes (body + delimiter)")
        self.keys = dict(keys) if keys else None
        self.max_body = max_frame - 1
        self.counts = DecodeCounts()
        #: {layout version: frames} of intact frames of another version (counted in `malformed`)
        self.versions: dict[int, int] = {}
        self.replay = ReplayGuard(accept_rewound=accept_rewound)
        self._buf = b""
        self._skipping = 0  # bytes of an overlong body skipped so far (0: not skipping)

    @property
    def authenticity_checked(self) -> bool:
        return self.keys is not None

    def take_rebased(self) -> dict[tuple[int, int], int]:
        """New baselines taken since the last call (operator-accepted rewinds):
        {(node, its seq): the node's previous newest seq}. For the caller of `feed`."""
        rebased = self.replay.rebased
        if not rebased:
            return {}
        out = {(node, seq): prev for node, seq, prev in rebased}
        rebased.clear()
        return out

    @property
    def pending(self) -> int:
        """Bytes held waiting for a delimiter (always <= max_frame)."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[P.Frame]:
        """Decode every frame completed by `data`; keep the unfinished tail."""
        out: list[P.Frame] = []
        if not data:
            return out
        if type(data) is not bytes:
            data = bytes(data)  # bytearray/memoryview from a port: frames must own immutable bytes
        parts = data.split(b"\x00")
        tail = parts.pop()
        c = self.counts
        if parts:
            first = parts[0]
            if self._skipping:
                c.malformed += 1
                c.bytes_discarded += self._skipping + len(first) + 1
                self._skipping = 0
                parts[0] = b""
            elif self._buf:
                parts[0] = self._buf + first
            self._buf = b""
            self._decode_bodies(parts, out)
        # The unfinished tail: buffer it, unless it is already too long for a frame.
        if self._skipping:
            self._skipping += len(tail)
        else:
            tail = self._buf + tail if self._buf else tail
            if len(tail) > self.max_body:
                self._skipping = len(tail)
                self._buf = b""
            else:
                self._buf = tail
        return out

    def _decode_bodies(self, bodies: list[bytes], out: list[P.Frame]) -> None:
        c = self.counts
        keys = self.keys
        max_body = self.max_body
        cobs_decode = cobs.decode
        crc = binascii.crc32
        residue = P.CRC_RESIDUE
        parse = P._parse
        lengths_of = P.LENGTHS.get
        min_len, max_len = P.MIN_RAW_LEN, P.MAX_RAW_LEN
        ACCEPTED, DUPLICATE, REWOUND = ReplayGuard.ACCEPTED, ReplayGuard.DUPLICATE, ReplayGuard.REWOUND
        for body in bodies:
            nb = len(body)
            if not nb:
                continue
            if nb > max_body:
                c.malformed += 1
                c.bytes_discarded += nb + 1
                continue
            try:
                raw = cobs_decode(body)
            except cobs.DecodeError:
                c.malformed += 1
                c.bytes_discarded += nb + 1
                continue
            n = len(raw)
            if n < min_len or n > max_len or crc(raw) != residue:
                old = P.old_version(raw)
                if old is not None:
                    self.versions[old] = self.versions.get(old, 0) + 1
                    c.malformed += 1
                elif n < min_len or n > max_len:
                    c.malformed += 1
                else:
                    c.crc_fail += 1
                c.bytes_discarded += nb + 1
                continue
            version = raw[0]
            try:
                lengths = lengths_of(version)
                if lengths is None:
                    raise P.VersionError(version)
                n_ropes = lengths.get(n)
                if n_ropes is None:
                    raise P.MalformedError("bad length")
                f = parse(raw, n_ropes, keys, version)
            except P.MacError:
                c.mac_fail += 1
                c.bytes_discarded += nb + 1
                continue
            except P.MalformedError as e:
                if isinstance(e, P.VersionError):
                    self.versions[e.version] = self.versions.get(e.version, 0) + 1
                c.malformed += 1
                c.bytes_discarded += nb + 1
                continue
            if keys is not None:
                verdict = self.replay.check(f.node, f.seq, raw)
                if verdict is not ACCEPTED:
                    if verdict is DUPLICATE:
                        c.duplicate += 1
                    else:
                        c.replayed += 1
                        if verdict is REWOUND:
                            c.rewound += 1
                    c.bytes_discarded += nb + 1
                    continue
            c.frames_ok += 1
            out.append(f)

    def finish(self) -> None:
        """End of input: an unterminated tail is a truncated frame (malformed, discarded)."""
        n = self._skipping or len(self._buf)
        if n:
            self.counts.malformed += 1
            self.counts.bytes_discarded += n
        self._buf, self._skipping = b"", 0

    def summary(self) -> str:
        """One line for a human: counts and whether authenticity was checked."""
        c = self.counts
        auth = "MAC checked" if self.authenticity_checked else "authenticity NOT checked (no keys)"
        line = (f"frames_ok={c.frames_ok} crc_fail={c.crc_fail} malformed={c.malformed} "
                f"mac_fail={c.mac_fail} replayed={c.replayed} rewound={c.rewound} duplicate={c.duplicate} "
                f"bytes_discarded={c.bytes_discarded}; {auth}")
        for version, n in sorted(self.versions.items()):
            line += (f"; malformed: {n} frame(s) of layout version {version} (this host decodes "
                     f"versions {', '.join(map(str, L.VERSIONS))}: a node with older or newer firmware)")
        for node, (top, boot) in sorted(self.replay.rewound.items()):
            line += (f"; node {node} REFUSED: its boot counter went back from {top} to {boot} "
                     f"(a replay, or the node lost its counter: an operator must accept node {node})")
        return line
