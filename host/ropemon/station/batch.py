"""Batch decoder for capture and log files: numpy over all frames at once, columns out.

Same rules and same counts as `StreamDecoder` fed the whole file then `finish()`
(tests/host/test_batch.py checks it): bodies between 0x00 delimiters are
grouped by length; for each valid frame length (of layout version 2 or 3: their
lengths never coincide) the COBS code chain, the CRC-32 and the field parse run as
array operations over every body of that length, and a frame whose version byte is
not that length's version is malformed, as the streaming decoder counts it. A
version 2 frame's ropes have pos_01mm POS_ABSENT and its stroke_mask is 0.
Bodies of any other length cannot be frames and go through the scalar decoder for
classification only (a frame of layout version 1 is one of them: its lengths are
never version 2's or 3's). MAC (hmac per frame) and the
anti-replay check (order dependent: replayed, rewound, duplicate) run per
frame, only when keys are given.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ropemon.station import protocol as P
from ropemon.station.decoder import DecodeCounts, ReplayGuard, StreamDecoder

L = P.L

_NP = {"B": "u1", "b": "i1", "H": "u2", "h": "i2", "I": "u4", "i": "i4"}


def _fields(fmt: str, names: tuple[str, ...], prefix: str = "") -> list[tuple[str, str]]:
    """numpy (name, type) pairs from a layout struct format: the layout stays the one definition."""
    codes = fmt[1:]
    assert fmt[0] == "<" and len(codes) == len(names)
    return [(prefix + n, "<" + _NP[c]) for n, c in zip(names, codes)]


_RECORDS = {2: (L.V2_ROPE_FMT, L.V2_ROPE_FIELDS, L.V2_TAIL_FMT, L.V2_TAIL_FIELDS),
            3: (L.ROPE_FMT, L.ROPE_FIELDS, L.TAIL_FMT, L.TAIL_FIELDS)}


def frame_dtype(n_ropes: int, version: int = L.VERSION) -> np.dtype:
    rope_fmt, rope_fields, tail_fmt, tail_fields = _RECORDS[version]
    f = _fields(L.HEADER_FMT, L.HEADER_FIELDS)
    for i in range(n_ropes):
        f += _fields(rope_fmt, rope_fields, f"r{i}_")
    f += _fields(tail_fmt, tail_fields)
    f += [("mac", f"V{L.MAC_LEN}"), ("crc", "<u4")]
    dt = np.dtype(f)
    assert dt.itemsize == L.frame_len(n_ropes, version)
    return dt


def _crc_table() -> np.ndarray:
    """CRC-32 (IEEE, reflected poly 0xEDB88320) byte table, as binascii.crc32 uses."""
    t = np.zeros(256, np.uint32)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0xEDB88320 if c & 1 else c >> 1
        t[i] = c
    return t


_CRC_TABLE = _crc_table()
COLUMNS = L.HEADER_FIELDS + L.TAIL_FIELDS
#: what a version 2 frame's columns hold where version 3 has a field it lacks
_V2_FILL = {"stroke_mask": 0, "pos_01mm": L.POS_ABSENT}
#: body length (COBS adds one byte) -> (version, rope count), over every version decoded
_VALID_LENS = {L.frame_len(n, v) + 1: (v, n) for v in L.VERSIONS for n in range(L.MAX_ROPES + 1)}
assert len(_VALID_LENS) == len(L.VERSIONS) * (L.MAX_ROPES + 1), "two versions share a frame length"


@dataclass
class BatchResult:
    """Good frames as columns (stream order) plus the counts.

    `columns[name]`: one array per header/tail field; `n_ropes` per frame;
    `ropes[field]`: (frames, MAX_ROPES) arrays, zero beyond a frame's n_ropes (pos_01mm
    POS_ABSENT in a version 2 frame);
    `mac`: (frames, MAC_LEN) uint8; `authenticated`: None when no keys were given.
    """

    columns: dict[str, np.ndarray]
    n_ropes: np.ndarray
    ropes: dict[str, np.ndarray]
    mac: np.ndarray
    authenticated: bool | None
    counts: DecodeCounts

    def __len__(self) -> int:
        return len(self.n_ropes)

    def frames(self) -> list[P.Frame]:
        """The same Frame objects the streaming decoder would give (slow: for tests and small files)."""
        out = []
        cols = [self.columns[k].tolist() for k in COLUMNS]
        ropes = [self.ropes[k].tolist() for k in L.ROPE_FIELDS]
        nr = self.n_ropes.tolist()
        for i in range(len(nr)):
            rs = tuple(P.Rope(*(r[i][j] for r in ropes)) for j in range(nr[i]))
            out.append(P.Frame(**{k: c[i] for k, c in zip(COLUMNS, cols)}, ropes=rs,
                               authenticated=self.authenticated, mac=bytes(self.mac[i])))
        return out


def _cobs_decode_rows(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """COBS-decode equal-length bodies (rows, each < 254 bytes): (raw rows, valid mask)."""
    n, width = m.shape
    rows = np.arange(n)
    pos = np.zeros(n, np.int64)
    is_code = np.zeros((n, width + 1), bool)
    active = rows
    while active.size:
        p = pos[active]
        is_code[active, p] = True
        code = m[active, p].astype(np.int64)
        # A code of 0xFF means "254 data bytes, no zero": impossible in a body this short.
        pos[active] = p + np.where(code == 0xFF, width + 1, code)
        active = active[pos[active] < width]
    valid = pos == width
    raw = np.where(is_code[:, 1:width], 0, m[:, 1:])
    return raw.astype(np.uint8), valid


def _crc_rows(raw: np.ndarray) -> np.ndarray:
    """CRC-32 of each row (binascii.crc32 of each), column by column over all rows."""
    crc = np.full(raw.shape[0], 0xFFFFFFFF, np.uint32)
    idx = np.empty(raw.shape[0], np.uint8)
    t = _CRC_TABLE
    for col in np.ascontiguousarray(raw.T):
        np.bitwise_xor(crc.astype(np.uint8), col, out=idx)  # the register's low byte ^ the next byte
        crc >>= 8
        crc ^= t[idx]
    return crc ^ np.uint32(0xFFFFFFFF)


def decode_bytes(data: bytes, keys: dict[int, bytes] | None = None) -> BatchResult:
    """Decode a whole capture. An unterminated tail counts as one malformed frame."""
    buf = np.frombuffer(data, np.uint8)
    counts = DecodeCounts()
    zeros = np.flatnonzero(buf == 0)
    starts = np.concatenate(([0], zeros[:-1] + 1)) if zeros.size else np.zeros(0, np.int64)
    lengths = zeros - starts
    tail = len(data) - (int(zeros[-1]) + 1 if zeros.size else 0)
    if tail:
        counts.malformed += 1
        counts.bytes_discarded += tail

    keys = dict(keys) if keys else None
    parts: list[tuple] = []  # (body indices, n_ropes, structured records, raw rows, version) per length
    valid_lens = _VALID_LENS
    odd = ~np.isin(lengths, list(valid_lens)) & (lengths > 0)
    if odd.any():
        # Cannot be frames; classify them exactly as the streaming decoder does.
        sd = StreamDecoder(keys)
        sd._decode_bodies([data[s:s + n] for s, n in zip(starts[odd].tolist(), lengths[odd].tolist())], [])
        counts.add(sd.counts)
    for body_len, (version, n_ropes) in valid_lens.items():
        idx = np.flatnonzero(lengths == body_len)
        if not idx.size:
            continue
        m = buf[starts[idx, None] + np.arange(body_len)]
        raw, ok = _cobs_decode_rows(m)
        bad = ~ok
        counts.malformed += int(bad.sum())
        crc_ok = _crc_rows(raw) == P.CRC_RESIDUE  # CRC-32 over the frame with its CRC field
        crc_bad = ok & ~crc_ok
        counts.crc_fail += int(crc_bad.sum())
        good = ok & crc_ok
        rec = np.ascontiguousarray(raw[good]).view(frame_dtype(n_ropes, version)).reshape(-1)
        want_kind = L.KIND_DATA if n_ropes else L.KIND_STATUS
        # another version byte at this length: an unknown version, or a known one of the wrong length
        sem = (rec["version"] == version) & (rec["kind"] == want_kind)
        counts.malformed += int((~sem).sum())
        counts.bytes_discarded += (int(bad.sum()) + int(crc_bad.sum()) + int((~sem).sum())) * (body_len + 1)
        parts.append((idx[good][sem], n_ropes, rec[sem], raw[good][sem], version))

    # Stream order across the length groups.
    order = np.argsort(np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int64), kind="stable")
    total = len(order)

    def gather(get, empty):
        return np.concatenate([get(p) for p in parts])[order] if parts else empty

    tail_types = dict(_fields(L.TAIL_FMT, L.TAIL_FIELDS))

    def column(p, k):
        if k in p[2].dtype.names:
            return p[2][k]
        return np.full(len(p[0]), _V2_FILL[k], tail_types[k])

    columns = {k: gather(lambda p, k=k: column(p, k), np.zeros(0, np.int64)) for k in COLUMNS}
    n_ropes = gather(lambda p: np.full(len(p[0]), p[1], np.uint8), np.zeros(0, np.uint8))
    rope_types = dict(_fields(L.ROPE_FMT, L.ROPE_FIELDS))
    ropes = {}
    for k, dt in rope_types.items():
        def block(p, k=k, dt=dt):
            b = np.zeros((len(p[0]), L.MAX_ROPES), dt)
            for i in range(p[1]):
                name = f"r{i}_{k}"
                b[:, i] = p[2][name] if name in p[2].dtype.names else _V2_FILL[k]
            return b
        ropes[k] = gather(block, np.zeros((0, L.MAX_ROPES), dt))
    mac = gather(lambda p: p[3][:, L.frame_len(p[1], p[4]) - L.MAC_LEN - L.CRC_LEN:][:, :L.MAC_LEN],
                 np.zeros((0, L.MAC_LEN), np.uint8))
    keep = np.ones(total, bool)
    if keys is not None:
        # Per frame: hmac cannot be vectorised, and the replay check depends on order.
        raw_rows = [row.tobytes() for p in parts for row in p[3]]
        guard = ReplayGuard()
        nodes = columns["node"].tolist()
        seqs = columns["seq"].tolist()
        for j, src in enumerate(order.tolist()):
            rawb = raw_rows[src]
            key = keys.get(nodes[j])
            ma = len(rawb) - L.MAC_LEN - L.CRC_LEN
            if key is None or P.mac_of(key, rawb[:ma]) != rawb[ma:ma + L.MAC_LEN]:
                counts.mac_fail += 1
            else:
                verdict = guard.check(nodes[j], seqs[j], rawb)
                if verdict is ReplayGuard.ACCEPTED:
                    continue
                if verdict is ReplayGuard.DUPLICATE:
                    counts.duplicate += 1
                else:
                    counts.replayed += 1
                    counts.rewound += int(verdict is ReplayGuard.REWOUND)
            counts.bytes_discarded += len(rawb) + 2
            keep[j] = False
        columns = {k: v[keep] for k, v in columns.items()}
        n_ropes = n_ropes[keep]
        ropes = {k: v[keep] for k, v in ropes.items()}
        mac = mac[keep]
    counts.frames_ok += int(keep.sum())
    return BatchResult(columns, n_ropes, ropes, mac, True if keys is not None else None, counts)


def decode_file(path, keys: dict[int, bytes] | None = None) -> BatchResult:
    with open(path, "rb") as fh:
        return decode_bytes(fh.read(), keys)
