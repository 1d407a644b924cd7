"""A built wheel works without the checkout: it carries the node firmware (package
`ropemon_firmware`, pyproject.toml maps it onto firmware/) and every module of host/ropemon,
and `ropemon.firmware` finds the firmware inside the install.

The wheel is built offline (--no-build-isolation: the setuptools of this venv, pinned in the
test extras) from a copy of the sources, so the repo gets no build/ or egg-info from it. It is
installed with --no-deps into a fresh venv; the runtime dependencies come from this venv's
site-packages through a .pth file, which puts that directory on sys.path without processing
its own .pth files (so not the editable install of ropemon). Every command runs from a
directory outside the repo, without PYTHONPATH.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
VECTORS = ROOT / "tests" / "vectors" / "frames.json"
JUNK = ("__pycache__", "*.pyc", "*.mpy", "*.egg-info")


def _run(cmd: list, cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=180)


def _tree(d: Path, pattern: str = "*") -> set[str]:
    """Files under d (relative, posix), without caches and build products."""
    return {p.relative_to(d).as_posix() for p in d.rglob(pattern)
            if p.is_file() and "__pycache__" not in p.parts and p.suffix not in (".pyc", ".mpy")}


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    for name in ("host", "firmware"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns(*JUNK))

    dist = tmp / "dist"
    r = _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
              "--no-index", "-w", dist, src], cwd=tmp)
    assert r.returncode == 0, ("wheel build failed (needs this venv's setuptools from the test "
                               "extras: `make` reinstalls them)\n" + r.stdout + r.stderr)
    (wheel,) = dist.glob("ropemon-*.whl")

    venv = tmp / "venv"
    r = _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=tmp)
    assert r.returncode == 0, r.stderr
    py = venv / "bin" / "python"
    r = _run([sys.executable, "-m", "pip", "--python", py, "install", "-q", "--no-deps", "--no-index",
              wheel], cwd=tmp)
    assert r.returncode == 0, r.stdout + r.stderr

    purelib = Path(_run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                        cwd=tmp).stdout.strip())
    (purelib / "ropemon_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")

    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    work = tmp / "elsewhere"
    work.mkdir()
    return {"venv": venv.resolve(), "py": py, "bin": venv / "bin", "env": env, "cwd": work}


def test_installed_package_and_firmware_come_from_the_wheel(installed):
    probe = ("import json, ropemon\n"
             "from ropemon import firmware\n"
             "print(json.dumps({'ropemon': ropemon.__file__, 'firmware': str(firmware.FIRMWARE_DIR)}))\n")
    r = _run([installed["py"], "-c", probe], cwd=installed["cwd"], env=installed["env"])
    assert r.returncode == 0, r.stderr
    where = {k: Path(v).resolve() for k, v in json.loads(r.stdout).items()}
    venv = installed["venv"]
    assert where["ropemon"].is_relative_to(venv), where   # not the editable install in host/
    fw = where["firmware"]
    assert fw.is_relative_to(venv) and fw.name == "ropemon_firmware", where
    # the whole firmware tree that deploy copies and replay runs, and nothing else
    assert _tree(fw) == _tree(ROOT / "firmware")
    assert {"main.py", "deployswap.py", "manifest.py", "node.json", "ropenode/layout.py"} <= _tree(fw)
    # every host module (pyproject.toml lists the subpackages by hand)
    assert _tree(ROOT / "host" / "ropemon", "*.py") <= _tree(where["ropemon"].parent, "*.py")
    # and the package data: the web face's templates, script, style and vendored uPlot
    web = ROOT / "host" / "ropemon" / "station" / "web"
    data = {p for p in _tree(web) if not p.endswith(".py")}
    assert "static/uplot/uPlot.iife.min.js" in data and "templates/live.html" in data
    assert data <= _tree(where["ropemon"].parent / "station" / "web")


def test_installed_command_runs_outside_the_repo(installed):
    ropemon = installed["bin"] / "ropemon"
    r = _run([ropemon, "--help"], cwd=installed["cwd"], env=installed["env"])
    assert r.returncode == 0, r.stderr
    assert "decode" in r.stdout

    # decode imports ropemon.station.protocol, which loads the frame layout from the firmware
    vec = json.loads(VECTORS.read_text())["good"][0]
    cap = installed["cwd"] / "capture.bin"
    cap.write_bytes(bytes.fromhex(vec["wire_hex"]))
    node = vec["fields"]["node"]
    r = _run([ropemon, "decode", cap.name], cwd=installed["cwd"],
             env={**installed["env"], f"ROPEMON_KEY_{node}": vec["key_hex"]})
    assert r.returncode == 0, r.stderr
    (frame,) = [json.loads(line) for line in r.stdout.splitlines()]
    assert frame["authenticated"] is True
    for k in ("node", "seq", "time_ms"):
        assert frame[k] == vec["fields"][k], (k, frame)
    assert "frames_ok=1" in r.stderr
