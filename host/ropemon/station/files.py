"""Bounded, typed reading of every input file a ropemon command takes (docs/operator.md, "Input files").

A bad file is refused with its name and the reason, never read for ever, never a traceback:

- only a regular file is read: a FIFO, a device (/dev/zero), a socket or a directory is refused
  from `os.stat` before anything is opened, and the file is opened with O_NONBLOCK so that a
  FIFO put in its place between the check and the open cannot hang the command either;
- each kind of file has a size limit (`LIMITS`): /dev/zero, a runaway log or a sparse file of
  terabytes is refused from its size, and a file that grows while read is cut at the limit;
- text must be UTF-8; JSON and TOML must parse and nest no deeper than `MAX_DEPTH` (the
  parsers' own RecursionError is caught); JSON must be standard JSON (no NaN or Infinity,
  no key twice);
- CSV fields are limited in length and the rows in number (`csv_rows`).

Every reader takes the caller's exception class (`error`, as `ropemon.station.tomlfields`
does), so a refusal reaches the command as the error it already reports; the default is
`FileRefused`, a ValueError. The messages start with the path. The product (station,
commissioning) and the lab all read through here.
"""
from __future__ import annotations

import csv
import json
import os
import stat
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

KB = 1 << 10
MB = 1 << 20
GB = 1 << 30

# The size limit of each kind of input (docs/operator.md, "Input files"): far above any real
# file of the kind, far below what would exhaust a hoist-room PC or a laptop.
MAX_NODE_JSON = 4 * MB        # node.json: a few tens of kB (station/physical.py: MAX_NODE_JSON_BYTES)
MAX_SITE_TOML = 1 * MB        # SITE.toml: a few kB
MAX_KEY_FILE = 4 * KB         # key_file: 32 to 64 hex digits
MAX_FIT_JSON = 4 * MB         # friction.json, compliance.json: a few kB
MAX_SCENARIO_TOML = 1 * MB    # a simulator scenario: a few kB
MAX_CSV = 256 * MB            # a test-bed record: a few MB
MAX_CSV_ROWS = 4_000_000      # rows of a test-bed record (an hour at 1 kHz is 3.6 million)
MAX_CSV_FIELD = 1 * KB        # one CSV field (a number or a column name)
MAX_RSENS = 1 * GB            # a sensor stream: a node's recording is at most 5.8 MB, a simulated duty cycle tens of MB
MAX_CAPTURE = 4 * GB          # receiver bytes for `ropemon decode` (read in chunks): months of frames
MAX_FRAMES_BIN = 1 * GB       # the firmware's radio bytes of a replay (read at once)
MAX_RUN_JSON = 64 * MB        # a run directory's truth.json, node-evaluated.json
MAX_DEPTH = 64                # nesting of a JSON or TOML document (a node.json nests 4 deep)

LIMITS = {
    "node.json": MAX_NODE_JSON, "SITE.toml": MAX_SITE_TOML, "key_file": MAX_KEY_FILE,
    "friction.json / compliance.json": MAX_FIT_JSON, "scenario TOML": MAX_SCENARIO_TOML,
    "test-bed CSV": MAX_CSV, "sensor stream (.rsens)": MAX_RSENS, "capture (ropemon decode)": MAX_CAPTURE,
    "radio bytes (frames.bin)": MAX_FRAMES_BIN, "run directory JSON": MAX_RUN_JSON,
}

SQLITE_MAGIC = b"SQLite format 3\x00"


class FileRefused(ValueError):
    """An input file that is not read: the message names the file and the reason."""


def size_text(n: float) -> str:
    """A byte count for a person: 4 MB, 1.5 GB, 512 bytes."""
    for unit, scale in (("GB", GB), ("MB", MB), ("kB", KB)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{int(n)} bytes"


def _too_large(size: int, max_bytes: int) -> str:
    """"5 GB, larger than the limit of 4 MB" (in bytes where the two would read the same)."""
    shown = size_text(size)
    if shown == size_text(max_bytes):
        shown = f"{size} bytes"
    return f"{shown}, larger than the limit of {size_text(max_bytes)}"


def _kind(mode: int) -> str | None:
    """What a non-regular file is, for the refusal; None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _refuse(error: type[Exception], path: Path | str, what: str, reason: str) -> Exception:
    """`error` with the message "PATH: REASON (the WHAT)"; its `path` and `reason` attributes
    let a caller word the message its own way (`ropemon.commission.site`)."""
    e = error(f"{path}: {reason}" + (f" (the {what})" if what else ""))
    e.path, e.reason = path, reason  # type: ignore[attr-defined]
    return e


def _allowed(mode: int, devices: bool) -> bool:
    return stat.S_ISREG(mode) or (devices and stat.S_ISCHR(mode))


def check_file(path: Path | str, what: str, max_bytes: int | None,
               error: type[Exception] = FileRefused, devices: bool = False) -> int:
    """The size of `path` if it is a regular file no larger than `max_bytes` (None: no limit);
    `error` naming the file and the fault otherwise. Nothing is opened: for a file handed to
    another program (the firmware under micropython) or to SQLite. `devices`: a character
    device is let through too (its size is 0; the caller's bounded read refuses /dev/zero)."""
    try:
        st = os.stat(path)
    except OSError as e:
        raise _refuse(error, path, what, f"cannot read: {e.strerror or e}") from None
    kind = _kind(st.st_mode)
    if not _allowed(st.st_mode, devices):
        raise _refuse(error, path, what, f"cannot read: {kind}, not a file")
    if max_bytes is not None and st.st_size > max_bytes:
        raise _refuse(error, path, what, _too_large(st.st_size, max_bytes))
    return st.st_size


def open_file(path: Path | str, what: str, max_bytes: int | None,
              error: type[Exception] = FileRefused, devices: bool = False) -> IO[bytes]:
    """`path` opened for binary reading after `check_file`; opened with O_NONBLOCK and
    checked again on the open descriptor, so nothing swapped in between can hang or slip
    through. The caller closes it and bounds what it reads."""
    check_file(path, what, max_bytes, error, devices)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise _refuse(error, path, what, f"cannot read: {e.strerror or e}") from None
    try:
        st = os.fstat(fd)
        kind = _kind(st.st_mode)
        if not _allowed(st.st_mode, devices):
            raise _refuse(error, path, what, f"cannot read: {kind}, not a file")
        if max_bytes is not None and st.st_size > max_bytes:
            raise _refuse(error, path, what, _too_large(st.st_size, max_bytes))
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_bytes(path: Path | str, what: str, max_bytes: int, error: type[Exception] = FileRefused) -> bytes:
    """The bytes of the regular file `path`, at most `max_bytes` (refused beyond)."""
    with open_file(path, what, max_bytes, error) as f:
        try:
            data = f.read(max_bytes + 1)
        except OSError as e:
            raise _refuse(error, path, what, f"cannot read: {e.strerror or e}") from None
    if len(data) > max_bytes:  # it grew after the check
        raise _refuse(error, path, what, f"larger than the limit of {size_text(max_bytes)}")
    return data


def read_text(path: Path | str, what: str, max_bytes: int, error: type[Exception] = FileRefused,
              encoding: str = "utf-8") -> str:
    """The text of `path` (UTF-8; "utf-8-sig" drops a byte-order mark): refused if it is not
    text in that encoding or holds a NUL byte (binary)."""
    data = read_bytes(path, what, max_bytes, error)
    try:
        text = data.decode(encoding)
    except UnicodeDecodeError as e:
        raise _refuse(error, path, what, f"not UTF-8 text (byte 0x{data[e.start]:02x} at offset "
                                         f"{e.start}): a binary file?") from None
    nul = text.find("\x00")
    if nul >= 0:
        raise _refuse(error, path, what, f"not text (a NUL byte at offset {nul}): a binary file?")
    return text


def depth_of(doc: Any) -> int:
    """How deeply lists and dicts nest in `doc` (a scalar: 0), without recursion."""
    depth = 0
    stack = [(doc, 1)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            v = list(v.values())
        elif not isinstance(v, list):
            continue
        depth = max(depth, d)
        if d > MAX_DEPTH:
            break
        stack.extend((x, d + 1) for x in v if isinstance(x, (dict, list)))
    return depth


def _check_depth(doc: Any, path, what: str, error: type[Exception]) -> Any:
    if depth_of(doc) > MAX_DEPTH:
        raise _refuse(error, path, what, f"nested deeper than {MAX_DEPTH} levels")
    return doc


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number (a number must be finite)")


def _pairs_once(pairs: list[tuple[str, Any]]) -> dict:
    out: dict = {}
    for k, v in pairs:
        if k in out:
            raise ValueError(f"key {k!r} twice in one object")
        out[k] = v
    return out


def parse_json(text: str | bytes, path: Path | str, what: str, error: type[Exception] = FileRefused,
               allow_nan: bool = False) -> Any:
    """A JSON document read from `path` (for its message): refused if not JSON, nested too
    deeply, with NaN or Infinity (unless `allow_nan`) or with a key twice in an object."""
    kw: dict[str, Any] = {"object_pairs_hook": _pairs_once}
    if not allow_nan:
        kw["parse_constant"] = _no_constant
    try:
        doc = json.loads(text, **kw)
    except RecursionError:
        raise _refuse(error, path, what, f"nested deeper than {MAX_DEPTH} levels") from None
    except UnicodeDecodeError as e:
        raise _refuse(error, path, what, f"not valid JSON: not UTF-8 text (offset {e.start}): a binary file?") from None
    except ValueError as e:  # json.JSONDecodeError and the hooks' refusals
        raise _refuse(error, path, what, f"not valid JSON: {e}") from None
    return _check_depth(doc, path, what, error)


def read_json(path: Path | str, what: str, max_bytes: int, error: type[Exception] = FileRefused,
              allow_nan: bool = False) -> Any:
    """The JSON document at `path` (`read_bytes`, then `parse_json`)."""
    return parse_json(read_bytes(path, what, max_bytes, error), path, what, error, allow_nan)


def parse_toml(text: str, path: Path | str, what: str, error: type[Exception] = FileRefused) -> dict:
    """A TOML document read from `path` (for its message): refused if not TOML or nested too deeply."""
    try:
        doc = tomllib.loads(text)
    except RecursionError:
        raise _refuse(error, path, what, f"nested deeper than {MAX_DEPTH} levels") from None
    except tomllib.TOMLDecodeError as e:
        raise _refuse(error, path, what, f"not valid TOML: {e}") from None
    return _check_depth(doc, path, what, error)


def read_toml(path: Path | str, what: str, max_bytes: int, error: type[Exception] = FileRefused) -> dict:
    """The TOML document at `path` (`read_text`, then `parse_toml`)."""
    return parse_toml(read_text(path, what, max_bytes, error), path, what, error)


def csv_rows(text: str, path: Path | str, what: str, error: type[Exception] = FileRefused, *,
             max_rows: int = MAX_CSV_ROWS, max_field: int = MAX_CSV_FIELD) -> Iterator[tuple[int, list[str]]]:
    """(line number, fields) of each row of CSV `text` read from `path`: refused at a field
    longer than `max_field` characters, at more than `max_rows` rows, or at a CSV syntax error,
    naming the line. The csv module's field limit is process-wide: it is set while a row is
    read and put back before the row is handed out."""
    import io

    reader = csv.reader(io.StringIO(text, newline=""))
    rows = 0
    while True:
        old = csv.field_size_limit(max_field)
        try:
            row = next(reader, None)
        except csv.Error as e:
            line = reader.line_num
            reason = (f"a field longer than {max_field} characters" if "field larger" in str(e)
                      else f"not CSV: {e}")
            raise _refuse(error, f"{path}:{line}", what, reason) from None
        finally:
            csv.field_size_limit(old)
        if row is None:
            return
        rows += 1
        if rows > max_rows:
            raise _refuse(error, path, what, f"more than {max_rows} rows")
        yield reader.line_num, row


def check_sqlite(path: Path | str, what: str = "database", error: type[Exception] = FileRefused,
                 new_ok: bool = False) -> Path:
    """`path` if it is an existing regular file that starts as an SQLite database does;
    `error` naming the file and the fault otherwise (nothing is written to it). `new_ok`: a
    log to append to, which may also not exist yet or be empty (SQLite makes it)."""
    if new_ok and not os.path.lexists(path):
        return Path(path)
    with open_file(path, what, None, error) as f:
        try:
            head = f.read(len(SQLITE_MAGIC))
        except OSError as e:
            raise _refuse(error, path, what, f"cannot read: {e.strerror or e}") from None
    if not head and new_ok:
        return Path(path)
    if not head:
        raise _refuse(error, path, what, "an empty file, not a ropemon database")
    if head != SQLITE_MAGIC:
        raise _refuse(error, path, what, "not an SQLite database, so not a ropemon database")
    return Path(path)


def write_private(path: Path | str, data: bytes) -> Path:
    """Write `data` to `path`, readable by its owner only (a key, a password hash, a secret): a
    new file created with mode 0600 from its first byte (O_CREAT | O_EXCL) beside `path`,
    synced, then renamed over it, so neither an earlier file's mode nor a half-written file is
    left behind."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o600)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return path
