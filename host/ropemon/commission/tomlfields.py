"""Checked reads of TOML documents: every refusal names the file or field and the reason.

One implementation for the site description (`ropemon.commission.site`, SiteError) and the
simulator's scenarios (`ropemon.lab.plant.scenario`, ScenarioError, also read by
`ropemon.lab.testbed`): each caller passes its own error class, so a site engineer
and a scenario author get the same words for the same fault.
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any


def load(path: Path | str, error: type[Exception]) -> dict:
    """The TOML document at `path`; `error` if the file cannot be read or is not TOML."""
    path = Path(path)
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except OSError as e:
        raise error(f"{path}: cannot read: {e.strerror}") from None
    except tomllib.TOMLDecodeError as e:
        raise error(f"{path}: not valid TOML: {e}") from None


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
