"""Checked reads of TOML (and JSON) documents: every refusal names the file or field and the reason.

One implementation for the site description (`ropemon.commission.site`, SiteError), the
simulator's scenarios (`ropemon.lab.plant.scenario`, ScenarioError, also read by
`ropemon.lab.testbed`) and node.json's `physical` section (`ropemon.station.physical`):
each caller passes its own error class, so a site engineer, a scenario author and an
operator get the same words for the same fault. Two forms of the same reads:

- functions on a dict and its dotted name (`number(t, key, where, error, ...)`), and
- `Table`, a dict with its name that remembers the keys read, so `finish()` refuses
  every other key: a misspelt field (or table) must not silently fall back to a default.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from ropemon.station import files

MISSING: Any = ...   # `default` of a required field


def load(path: Path | str, error: type[Exception], what: str = "", max_bytes: int = files.MAX_SITE_TOML) -> dict:
    """The TOML document at `path`; `error` if the file cannot be read (not a regular file,
    larger than `max_bytes`), is not TOML or nests too deeply (`ropemon.station.files`)."""
    return files.read_toml(path, what, max_bytes, error)


def check_number(v: Any, name: str, error: type[Exception], *, gt: float | None = None,
                 ge: float | None = None, le: float | None = None, lt: float | None = None) -> float:
    """`v` as a float: a finite int or float (not a bool) within the bounds given."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise error(f"{name}: must be a number, got {v!r}")
    v = float(v)
    if not math.isfinite(v):
        raise error(f"{name}: must be finite, got {v!r}")
    if gt is not None and not v > gt:
        raise error(f"{name}: must be > {gt:g}, got {v:g}")
    if ge is not None and not v >= ge:
        raise error(f"{name}: must be >= {ge:g}, got {v:g}")
    if lt is not None and not v < lt:
        raise error(f"{name}: must be < {lt:g}, got {v:g}")
    if le is not None and not v <= le:
        raise error(f"{name}: must be <= {le:g}, got {v:g}")
    return v


def check_int(v: Any, name: str, error: type[Exception], *, lo: int | None = None,
              hi: int | None = None) -> int:
    """`v` as an int (not a bool, not a float) within lo..hi."""
    if isinstance(v, bool) or not isinstance(v, int):
        raise error(f"{name}: must be an integer, got {v!r}")
    if lo is not None and v < lo:
        raise error(f"{name}: must be >= {lo}, got {v}")
    if hi is not None and v > hi:
        raise error(f"{name}: must be <= {hi}, got {v}")
    return v


def field_name(where: str, key: str | int) -> str:
    """`where.key` (`where[i]` for a list index); `key` alone at the top level."""
    if isinstance(key, int):
        return f"{where}[{key}]"
    return f"{where}.{key}" if where else key


def raw(t: dict, key: str, where: str, error: type[Exception], default: Any = MISSING) -> Any:
    """t[key] unchecked; `default` when absent, or `error` "missing" without a default."""
    if key not in t:
        if default is MISSING:
            raise error(f"{field_name(where, key)}: missing")
        return default
    return t[key]


def number(t: dict, key: str, where: str, error: type[Exception], default: Any = MISSING, *,
           gt: float | None = None, ge: float | None = None, le: float | None = None,
           lt: float | None = None) -> float:
    """t[key] (or the default) as a checked float (`check_number`)."""
    return check_number(raw(t, key, where, error, default), field_name(where, key), error,
                        gt=gt, ge=ge, le=le, lt=lt)


def integer(t: dict, key: str, where: str, error: type[Exception], default: Any = MISSING, *,
            lo: int | None = None, hi: int | None = None) -> int:
    """t[key] (or the default) as a checked int (`check_int`)."""
    return check_int(raw(t, key, where, error, default), field_name(where, key), error, lo=lo, hi=hi)


def string(t: dict, key: str, where: str, error: type[Exception], default: Any = MISSING, *,
           choices: tuple[str, ...] | None = None) -> str:
    """t[key] (or the default) as a string, one of `choices` when given."""
    v = raw(t, key, where, error, default)
    name = field_name(where, key)
    if not isinstance(v, str):
        raise error(f"{name}: must be a string, got {v!r}")
    if choices is not None and v not in choices:
        raise error(f"{name}: must be one of {', '.join(choices)}, got {v!r}")
    return v


def boolean(t: dict, key: str, where: str, error: type[Exception], default: Any = MISSING) -> bool:
    """t[key] (or the default) as true or false (not 0 or 1)."""
    v = raw(t, key, where, error, default)
    if not isinstance(v, bool):
        raise error(f"{field_name(where, key)}: must be true or false, got {v!r}")
    return v


def table(t: dict, key: str, where: str, error: type[Exception], default: Any = MISSING) -> dict:
    """t[key] (or the default), which must be a table."""
    v = raw(t, key, where, error, default)
    if not isinstance(v, dict):
        raise error(f"{field_name(where, key)}: must be a table, got {type(v).__name__}")
    return v


def array(t: dict, key: str, where: str, error: type[Exception], default: Any = MISSING, *,
          length: int | None = None, min_len: int = 0, max_len: int | None = None,
          what: str = "values") -> list:
    """t[key] (or the default) as a list, of exactly `length` entries when given, else of
    min_len..max_len; the entries are the caller's to check."""
    v = raw(t, key, where, error, default)
    name = field_name(where, key)
    if not isinstance(v, list):
        raise error(f"{name}: must be a list of {what}, got {type(v).__name__}")
    if length is not None and len(v) != length:
        raise error(f"{name}: must have {length} entries ({what}), got {len(v)}")
    if len(v) < min_len or (max_len is not None and len(v) > max_len):
        span = f"{min_len}..{max_len}" if max_len is not None else f"at least {min_len}"
        raise error(f"{name}: must have {span} entries ({what}), got {len(v)}")
    return v


def pair(t: dict, key: str, where: str, error: type[Exception], default: Any = MISSING, *,
         equal_ok: bool = False) -> tuple[float, float]:
    """t[key] (or the default) as [low, high], two numbers with high > low (>= with equal_ok)."""
    v = raw(t, key, where, error, default)
    name = field_name(where, key)
    if not isinstance(v, list) or len(v) != 2:
        raise error(f"{name}: must be [low, high], got {v!r}")
    lo, hi = (check_number(x, name, error) for x in v)
    if not (hi >= lo if equal_ok else hi > lo):
        raise error(f"{name}: high must be {'>=' if equal_ok else '>'} low, got {v!r}")
    return lo, hi


def known(t: dict, where: str, keys: set[str] | frozenset[str], error: type[Exception]) -> None:
    """Refuse a key of t not in `keys`, naming the first (sorted)."""
    unknown = sorted(set(t) - set(keys))
    if unknown:
        raise error(f"{field_name(where, unknown[0])}: unknown field")


class Table:
    """A table with its dotted name, so every error names the field; it remembers the keys
    read, and `finish()` refuses the others (`known`)."""

    def __init__(self, data: Any, name: str, error: type[Exception] = ValueError):
        if not isinstance(data, dict):
            raise error(f"{name}: must be a table, got {type(data).__name__}")
        self.data = data
        self.name = name
        self.error = error
        self.used: set[str] = set()

    def field(self, key: str | int) -> str:
        return field_name(self.name, key)

    def has(self, key: str) -> bool:
        return key in self.data

    def raw(self, key: str, default: Any = MISSING) -> Any:
        self.used.add(key)
        return raw(self.data, key, self.name, self.error, default)

    def table(self, key: str, default: Any = MISSING) -> "Table":
        self.used.add(key)
        return type(self)(table(self.data, key, self.name, self.error, default), self.field(key), self.error)

    def number(self, key: str, default: Any = MISSING, *, gt: float | None = None, ge: float | None = None,
               le: float | None = None, lt: float | None = None) -> float:
        self.used.add(key)
        return number(self.data, key, self.name, self.error, default, gt=gt, ge=ge, le=le, lt=lt)

    def integer(self, key: str, default: Any = MISSING, *, lo: int | None = None, hi: int | None = None) -> int:
        self.used.add(key)
        return integer(self.data, key, self.name, self.error, default, lo=lo, hi=hi)

    def string(self, key: str, default: Any = MISSING, *, choices: tuple[str, ...] | None = None) -> str:
        self.used.add(key)
        return string(self.data, key, self.name, self.error, default, choices=choices)

    def boolean(self, key: str, default: Any = MISSING) -> bool:
        self.used.add(key)
        return boolean(self.data, key, self.name, self.error, default)

    def array(self, key: str, default: Any = MISSING, **kw) -> list:
        self.used.add(key)
        return array(self.data, key, self.name, self.error, default, **kw)

    def pair(self, key: str, default: Any = MISSING, *, equal_ok: bool = False) -> tuple[float, float]:
        self.used.add(key)
        return pair(self.data, key, self.name, self.error, default, equal_ok=equal_ok)

    def finish(self) -> None:
        """Refuse unknown keys: a misspelt field must not silently fall back to a default."""
        known(self.data, self.name, self.used, self.error)
