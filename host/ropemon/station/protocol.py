"""Radio frames on the host: the `Frame` type, encoding (tests, vectors, radio model)
and decoding of one frame, with a distinct exception per failure.

The byte layout is firmware/ropenode/layout.py, imported here, never restated:
raw = header + ropes + tail + mac + crc; wire = 0x00 + COBS(raw) + 0x00.
This host decodes the layout versions L.VERSIONS side by side (2 and 3: a mine
upgrades its nodes one cage at a time): the CRC-32 is checked over the frame, then
the version byte picks the layout and the length must be one of that version's. A
version 2 frame decodes with every rope's pos_01mm POS_ABSENT and stroke_mask 0
(`Frame.version` tells which). A frame of version 1 (with a CRC-16) is recognised
by its own CRC and refused as `VersionError`, so an old node shows as such, not as
radio noise; so is an intact frame of a version not in L.VERSIONS.
"""
from __future__ import annotations

import binascii
import hashlib
import hmac
import struct
from dataclasses import dataclass, field
from functools import partial
from typing import NamedTuple

from cobs import cobs

from ropemon.firmware import node_module

L = node_module("layout")

HEADER = struct.Struct(L.HEADER_FMT)
ROPE = struct.Struct(L.ROPE_FMT)   # version 3 (L.VERSION)
TAIL = struct.Struct(L.TAIL_FMT)
V2_ROPE = struct.Struct(L.V2_ROPE_FMT)
V2_TAIL = struct.Struct(L.V2_TAIL_FMT)
#: version -> (rope struct, tail struct)
RECORDS = {2: (V2_ROPE, V2_TAIL), 3: (ROPE, TAIL)}
CRC = struct.Struct("<I")
MAX_RAW_LEN = max(L.frame_len(L.MAX_ROPES, v) for v in L.VERSIONS)
MIN_RAW_LEN = min(L.frame_len(0, v) for v in L.VERSIONS)
#: version -> {raw length: rope count}: the lengths a frame of that version can have
LENGTHS = {v: {L.frame_len(n, v): n for n in range(L.MAX_ROPES + 1)} for v in L.VERSIONS}
#: Longest COBS body between two delimiters a valid frame can have (the wire adds one 0x00 each side).
MAX_BODY_LEN = L.MAX_WIRE_LEN - 2
#: CRC-32 of a whole raw frame, its CRC field included, when that field is right: the
#: standard residue of CRC-32 (IEEE). One C call over the frame, no slice, no unpack.
CRC_RESIDUE = 0x2144DF1C
#: Version 1 of the layout (version 2's records, a CRC-16/CCITT-FALSE instead of the
#: CRC-32): raw bytes without ropes, and per rope. Only to name such a frame when it
#: comes (`old_version`).
V1_FIXED_LEN = L.V2_FIXED_LEN - 2
V1_ROPE_LEN = L.V2_ROPE_LEN
_NO_MAC = bytes(L.MAC_LEN)
_NH = len(L.HEADER_FIELDS)
_NR = len(L.ROPE_FIELDS)
_NR2 = len(L.V2_ROPE_FIELDS)

# One struct per version and rope count: header + ropes + tail in a single unpack.
_BODY = {v: tuple(struct.Struct("<" + L.HEADER_FMT[1:] + rope[1:] * n + tail[1:])
                  for n in range(L.MAX_ROPES + 1))
         for v, rope, tail in ((2, L.V2_ROPE_FMT, L.V2_TAIL_FMT), (3, L.ROPE_FMT, L.TAIL_FMT))}

DAN_TO_N = 10  # 1 daN = 10 N


class FrameError(ValueError):
    """A frame that must not be used as data."""


class CrcError(FrameError):
    """CRC-32 mismatch: bytes were corrupted on the way (or radio noise)."""


class MalformedError(FrameError):
    """Intact CRC (or not checkable) but not a frame this host understands."""


class VersionError(MalformedError):
    """An intact frame of a layout version not in L.VERSIONS (its own CRC checks)."""

    def __init__(self, version: int):
        super().__init__(f"frame of layout version {version}: this host decodes versions "
                         f"{', '.join(map(str, L.VERSIONS))} only")
        self.version = version


class MacError(FrameError):
    """MAC mismatch or no key for the node while keys are configured."""


class Rope(NamedTuple):
    """One rope's record in a frame (units as in docs/protocol.md).

    A NamedTuple, not a dataclass: it is built four times per frame on the hot path.
    """

    mean_dan: int   # compensated tension, window mean; TENSION_ABSENT: no healthy sample
    min_dan: int
    max_dan: int
    raw_kpa: int    # uncompensated tap pressure, window mean; RAW_KPA_ABSENT: none
    # piston position, window mean, 0.1 mm from mid-stroke (x > 0: pulled out by the rope);
    # POS_ABSENT: no healthy displacement sample, or a version 2 frame (no position)
    pos_01mm: int = L.POS_ABSENT

    @property
    def absent(self) -> bool:
        """The rope's sensor gave no healthy sample in the window: no tension to show."""
        return self.mean_dan == L.TENSION_ABSENT

    @property
    def mean_n(self) -> int | None:
        return None if self.mean_dan == L.TENSION_ABSENT else self.mean_dan * DAN_TO_N

    @property
    def position_m(self) -> float | None:
        """The piston's window-mean position in m from mid-stroke; None when absent."""
        return None if self.pos_01mm == L.POS_ABSENT else self.pos_01mm * 1e-4


@dataclass(slots=True)
class Frame:
    """One decoded radio frame. `authenticated` is None when no key was configured.
    `stroke_mask` (version 3; 0 in a version 2 frame): bit i = rope i's piston within the
    stroke margin of its retracted end during the window, bit 4+i = of its extended end.

    Treat as read-only; not frozen because a frozen dataclass costs ~1 us more per frame.
    """

    version: int
    kind: int
    node: int
    fault_mask: int
    seq: int
    time_ms: int
    status: int
    ropes: tuple[Rope, ...]
    depth_mm: int
    speed_mm_s: int
    battery_mv: int
    oil_temp_cc: int
    stroke_mask: int = 0
    authenticated: bool | None = None
    mac: bytes = field(default=_NO_MAC, repr=False)

    @property
    def status_flags(self) -> list[str]:
        """Names of the set status bits (layout.STATUS_BITS order)."""
        return [name for name, bit in L.STATUS_BITS if self.status & bit]

    @property
    def held_back(self) -> tuple[int, ...]:
        """The ropes (from 0) whose compensation the node held back at rest in the window: the
        piston's own travel did not support the seal friction its model held (docs/model.md,
        "Do no harm"); their tension is nearer p A. Empty in frames of nodes without it."""
        bits = (self.status & L.ST_HELD_BACK_MASK) >> L.ST_HELD_BACK_SHIFT
        return tuple(i for i in range(len(self.ropes)) if bits >> i & 1)

    @property
    def tensions_n(self) -> list[int | None]:
        """Compensated mean tension of each rope in N; None for an absent rope."""
        return [r.mean_n for r in self.ropes]

    @property
    def total_dan(self) -> int | None:
        """Sum of the rope tensions; None when a rope is absent (the sum would be wrong)."""
        if any(r.mean_dan == L.TENSION_ABSENT for r in self.ropes):
            return None
        return sum(r.mean_dan for r in self.ropes)

    @property
    def oil_temp_c(self) -> float | None:
        """Oil temperature in degC, None when the node has no temperature input."""
        if self.oil_temp_cc == L.OIL_TEMP_ABSENT:
            return None
        return self.oil_temp_cc / 100

    @property
    def stroke_low(self) -> list[bool]:
        """Per rope: its piston came within the stroke margin of its retracted (low x) end."""
        return [bool(self.stroke_mask >> (L.STROKE_LOW_SHIFT + i) & 1) for i in range(len(self.ropes))]

    @property
    def stroke_high(self) -> list[bool]:
        """Per rope: its piston came within the stroke margin of its extended (high x) end."""
        return [bool(self.stroke_mask >> (L.STROKE_HIGH_SHIFT + i) & 1) for i in range(len(self.ropes))]

    def to_dict(self) -> dict:
        """Plain JSON-ready form: every payload field, ropes as a list of dicts."""
        return {
            "node": self.node,
            "seq": self.seq,
            "version": self.version,
            "kind": self.kind,
            "time_ms": self.time_ms,
            "status": self.status,
            "status_flags": self.status_flags,
            "fault_mask": self.fault_mask,
            "ropes": [
                {"mean_dan": r.mean_dan, "min_dan": r.min_dan, "max_dan": r.max_dan, "raw_kpa": r.raw_kpa,
                 "absent": r.mean_dan == L.TENSION_ABSENT, "pos_01mm": r.pos_01mm,
                 "position_absent": r.pos_01mm == L.POS_ABSENT}
                for r in self.ropes
            ],
            "depth_mm": self.depth_mm,
            "speed_mm_s": self.speed_mm_s,
            "battery_mv": self.battery_mv,
            "oil_temp_cc": self.oil_temp_cc,
            "stroke_mask": self.stroke_mask,
            "authenticated": self.authenticated,
            "mac": self.mac.hex(),
        }

    def same_payload(self, other: "Frame") -> bool:
        """True when both carry the same bytes on the radio (authenticity aside)."""
        return (self.node, self.seq, self.mac, self.ropes, self._rest()) == (
            other.node, other.seq, other.mac, other.ropes, other._rest())

    def _rest(self) -> tuple:
        return (self.version, self.kind, self.fault_mask, self.time_ms, self.status,
                self.depth_mm, self.speed_mm_s, self.battery_mv, self.oil_temp_cc, self.stroke_mask)


_make_rope = partial(tuple.__new__, Rope)
_ROPE_SLICES = tuple(tuple(slice(i, i + _NR) for i in range(_NH, _NH + _NR * n, _NR))
                     for n in range(L.MAX_ROPES + 1))
_V2_ROPE_SLICES = tuple(tuple(slice(i, i + _NR2) for i in range(_NH, _NH + _NR2 * n, _NR2))
                        for n in range(L.MAX_ROPES + 1))
_POS_ABSENT = (L.POS_ABSENT,)


KEY_LEN_MIN, KEY_LEN_MAX = 16, 32  # docs/config.md: node.key
KEY_ENV_PREFIX = "ROPEMON_KEY_"    # ROPEMON_KEY_<NODE>=HEX in the environment
#: Why `--key NODE:HEX` is refused, and what to use instead (`ropemon decode`, `ropemon monitor`).
KEY_ON_COMMAND_LINE = ("refused: a key on the command line can be read by every user of this computer "
                       "(ps, /proc/PID/cmdline) and stays in the shell's history; give it as --key-file "
                       "NODE:PATH (a file holding the key in hex, readable by its owner only), as "
                       f"{KEY_ENV_PREFIX}<NODE>=HEX in the environment, or with --config node.json")


def _node_number(text: str, what: str) -> int:
    try:
        node = int(text, 10)
    except ValueError:
        raise ValueError(f"{what}: node {text!r} is not an integer") from None
    if not 0 <= node <= 255:
        raise ValueError(f"{what}: node {node} outside 0..255")
    return node


def _key_bytes(text: str, what: str) -> bytes:
    """The key in hex `text`; ValueError names `what` (never the key itself)."""
    try:
        key = bytes.fromhex(text.strip())
    except ValueError:
        raise ValueError(f"{what}: the key is not hex") from None
    if not KEY_LEN_MIN <= len(key) <= KEY_LEN_MAX:
        raise ValueError(f"{what}: the key is {len(key)} bytes, expected {KEY_LEN_MIN}..{KEY_LEN_MAX}")
    return key


def read_key_file(spec: str) -> tuple[int, bytes]:
    """`--key-file NODE:PATH` -> (node, key): PATH holds the key in hex (as SITE.toml's
    key_file). Refused, with the reason: a file that group or others may read or write (a key
    must be its owner's only: chmod 600), an unreadable or oversized one, a key that is not
    16..32 bytes of hex."""
    import os
    import stat

    from ropemon.station import files

    node_s, found, path = spec.partition(":")
    what = f"--key-file {spec}"
    if not found or not path:
        raise ValueError(f"{what}: expected NODE:PATH")
    node = _node_number(node_s, what)
    files.check_file(path, "key file", files.MAX_KEY_FILE, ValueError)
    mode = stat.S_IMODE(os.stat(path).st_mode)
    if os.name == "posix" and mode & 0o077:
        raise ValueError(f"{what}: refused: {path} has mode {mode:04o}, so group or others may read (or change) "
                         f"the key; a key file must be its owner's only: chmod 600 {path}")
    return node, _key_bytes(files.read_text(path, "key file", files.MAX_KEY_FILE, ValueError), what)


def keys_from_environment(env) -> list[tuple[str, tuple[int, bytes]]]:
    """[(variable, (node, key))] of the variables ROPEMON_KEY_<NODE>=HEX in `env`, by name."""
    return [(name, (_node_number(name[len(KEY_ENV_PREFIX):], name), _key_bytes(value, name)))
            for name, value in sorted(env.items()) if name.startswith(KEY_ENV_PREFIX)]


def load_node_keys(path) -> dict[int, bytes]:
    """node id -> key from a node.json: its node section's `node_id` and `key`, the copy the
    node reads, after the file's SHA-256 is checked (`physical.check_digest`: a file changed
    since `ropemon config` wrote it is refused). ValueError names the fault."""
    from ropemon.station import files  # bounded: a FIFO, /dev/zero or a deep nest is refused, named
    from ropemon.station.physical import check_digest, node_identity

    doc = files.read_json(path, "node.json", files.MAX_NODE_JSON, ValueError, allow_nan=True)
    check_digest(doc, path)
    return dict([node_identity(doc, path)])


def keys_from_options(key_files: list[str], configs: list[str], accept_rewound: list[int] | None = None,
                      env=None) -> dict[int, bytes]:
    """node id -> key from the repeatable command-line options `--key-file NODE:PATH` and
    `--config node.json` and the environment's ROPEMON_KEY_<NODE>=HEX (`env`, default
    os.environ), merged. ValueError names the fault: a bad key or key file, a file that is
    not a node.json, one node given two different keys (which one is right cannot be
    guessed), or `--accept-rewound` without any key (nothing is refused then)."""
    import os

    out: dict[int, bytes] = {}
    sources: dict[int, str] = {}
    given = [(f"--key-file {k}", read_key_file(k)) for k in key_files]
    given += keys_from_environment(os.environ if env is None else env)
    given += [(f"--config {p}", kv) for p in configs for kv in load_node_keys(p).items()]
    for source, (node, key) in given:
        if node in out and out[node] != key:
            raise ValueError(f"node {node}: {sources[node]} and {source} give different keys")
        out[node], sources[node] = key, source
    if accept_rewound and not out:
        raise ValueError(f"--accept-rewound needs node keys (--key-file, {KEY_ENV_PREFIX}<NODE> or --config): "
                         "without keys no frame is refused")
    return out


def mac_of(key: bytes, body: bytes) -> bytes:
    """Truncated HMAC-SHA256 of everything before the MAC field."""
    return hmac.digest(key, body, hashlib.sha256)[: L.MAC_LEN]


def crc32(data: bytes | bytearray) -> int:
    """CRC-32 (IEEE 802.3), same as ropenode.crc32."""
    return binascii.crc32(data)


def old_version(raw: bytes) -> int | None:
    """1 when `raw` (COBS removed) is an intact frame of layout version 1 (30 + 8 N
    bytes, CRC-16/CCITT-FALSE), else None. Called only on a frame that failed
    the length or CRC-32 check: names an old node's frames."""
    n = len(raw)
    if (n >= V1_FIXED_LEN and raw[0] == 1 and (n - V1_FIXED_LEN) % V1_ROPE_LEN == 0
            and n <= V1_FIXED_LEN + V1_ROPE_LEN * L.MAX_ROPES
            and binascii.crc_hqx(raw[:-2], 0xFFFF) == raw[-2] | (raw[-1] << 8)):
        return 1
    return None


def encode_frame(
    *,
    node: int,
    seq: int,
    time_ms: int = 0,
    ropes: tuple | list = (),
    status: int = 0,
    fault_mask: int = 0,
    depth_mm: int = 0,
    speed_mm_s: int = 0,
    battery_mv: int = 0,
    oil_temp_cc: int = L.OIL_TEMP_ABSENT,
    stroke_mask: int = 0,
    kind: int | None = None,
    version: int = L.VERSION,
    key: bytes | None = None,
) -> tuple[bytes, bytes]:
    """Build one frame of layout `version` (2 or 3; another number: a version 3 body with
    that version byte, a test aid); return (raw, wire). `ropes` items: Rope, 4-tuples
    (mean, min, max, raw_kpa: the position absent) or 5-tuples (with pos_01mm). A
    version 2 frame carries neither positions nor `stroke_mask` (refused if given).

    kind defaults to DATA when ropes are given, STATUS otherwise. Without a key
    the MAC field is zero (a host-side test aid: real nodes always have a key).
    """
    if kind is None:
        kind = L.KIND_DATA if ropes else L.KIND_STATUS
    rope_s, tail_s = RECORDS.get(version, RECORDS[3])
    body = bytearray(HEADER.pack(version, kind, node, fault_mask, seq, time_ms, status))
    for r in ropes:
        r = tuple(r)
        if rope_s is V2_ROPE:
            if len(r) == 5 and r[4] != L.POS_ABSENT:
                raise ValueError("a version 2 frame carries no piston position")
            body += V2_ROPE.pack(*r[:4])
        else:
            body += ROPE.pack(*r) if len(r) == 5 else ROPE.pack(*r, L.POS_ABSENT)
    if tail_s is V2_TAIL:
        if stroke_mask:
            raise ValueError("a version 2 frame carries no stroke_mask")
        body += V2_TAIL.pack(depth_mm, speed_mm_s, battery_mv, oil_temp_cc)
    else:
        body += TAIL.pack(depth_mm, speed_mm_s, battery_mv, oil_temp_cc, stroke_mask)
    body += mac_of(key, bytes(body)) if key is not None else _NO_MAC
    body += CRC.pack(crc32(body))
    raw = bytes(body)
    return raw, b"\x00" + cobs.encode(raw) + b"\x00"


def decode_wire(body: bytes) -> bytes:
    """One frame's COBS body -> raw frame bytes. The body may come with its 0x00
    delimiters (the wire bytes of one frame): a body holds no 0x00, so they are dropped."""
    if body[:1] == b"\x00" or body[-1:] == b"\x00":
        body = body.strip(b"\x00")
    if len(body) > MAX_BODY_LEN:
        raise MalformedError(f"frame too long: {len(body)} bytes > {MAX_BODY_LEN}")
    try:
        return cobs.decode(body)
    except cobs.DecodeError as e:
        raise MalformedError(f"bad COBS: {e}") from None


def decode_raw(raw: bytes, keys: dict[int, bytes] | None = None) -> Frame:
    """Check and parse one raw frame (COBS already removed).

    Raises CrcError, MalformedError (VersionError: a frame of a layout version not
    in L.VERSIONS) or MacError; the CRC is checked first, then the version byte picks
    the layout and the length must be that version's, then the MAC. With `keys` (node ->
    key) the MAC must match and a node without a key is refused; without keys the
    frame's `authenticated` is None (authenticity not checked).
    """
    n = len(raw)
    if n < MIN_RAW_LEN or n > MAX_RAW_LEN or binascii.crc32(raw) != CRC_RESIDUE:
        old = old_version(raw)
        if old is not None:
            raise VersionError(old)
        if n < MIN_RAW_LEN:
            raise MalformedError(f"frame too short: {n} bytes < {MIN_RAW_LEN}")
        if n > MAX_RAW_LEN:
            raise MalformedError(f"frame too long: {n} bytes > {MAX_RAW_LEN}")
        raise CrcError("CRC mismatch")
    version = raw[0]
    lengths = LENGTHS.get(version)
    if lengths is None:
        raise VersionError(version)
    n_ropes = lengths.get(n)
    if n_ropes is None:
        raise MalformedError(length_refusal(n, version))
    return _parse(raw, n_ropes, keys, version)


def length_refusal(n: int, version: int) -> str:
    """Why a CRC-intact frame of `version` and `n` bytes is refused: its length is not one
    of that version's."""
    fixed, rope = L.frame_len(0, version), L.frame_len(1, version) - L.frame_len(0, version)
    return (f"length {n} is not a version {version} frame's ({fixed} + {rope} x ropes, "
            f"0..{L.MAX_ROPES} ropes)")


def _parse(raw: bytes, n_ropes: int, keys: dict[int, bytes] | None, version: int = L.VERSION) -> Frame:
    """Fields of a CRC-checked raw frame of layout `version` (in L.VERSIONS, its length
    checked) and n_ropes ropes; semantic and MAC checks."""
    v = _BODY[version][n_ropes].unpack_from(raw)
    kind, node = v[1], v[2]
    if kind == L.KIND_DATA:
        if n_ropes == 0:
            raise MalformedError("data frame without ropes")
    elif kind == L.KIND_STATUS:
        if n_ropes:
            raise MalformedError("status frame with rope records")
    else:
        raise MalformedError(f"unknown frame kind {kind}")
    mac_at = len(raw) - L.MAC_LEN - L.CRC_LEN
    mac = raw[mac_at: mac_at + L.MAC_LEN]
    authenticated = None
    if keys:
        key = keys.get(node)
        if key is None:
            raise MacError(f"no key configured for node {node}")
        if not hmac.compare_digest(mac_of(key, raw[:mac_at]), mac):
            raise MacError(f"MAC mismatch for node {node}")
        authenticated = True
    if version == 3:
        t = _NH + _NR * n_ropes
        ropes = tuple(map(_make_rope, map(v.__getitem__, _ROPE_SLICES[n_ropes])))
        return Frame(version, kind, node, v[3], v[4], v[5], v[6], ropes,
                     v[t], v[t + 1], v[t + 2], v[t + 3], v[t + 4], authenticated, mac)
    t = _NH + _NR2 * n_ropes
    ropes = tuple([_make_rope(v[s] + _POS_ABSENT) for s in _V2_ROPE_SLICES[n_ropes]])
    return Frame(version, kind, node, v[3], v[4], v[5], v[6], ropes,
                 v[t], v[t + 1], v[t + 2], v[t + 3], 0, authenticated, mac)
