"""The firmware test files run on the official 32-bit MicroPython (WebAssembly port) too.

Every file tests/run_micropython.py runs under the unix port (tests/firmware/test_*.py not
named *_cpython.py, found by the same discovery, so a new file runs here too) runs here
through Node.js (tests/wasm/run_wasm.mjs), with the same driver and PASS/FAIL protocol, one
step at a time (STEP_DRIVER, `--step _step`): this port's gc.collect() only marks a
collection, which runs when the outermost call from JavaScript returns, so the driver's
collections between a test's steps are top-level calls from Node.js (that is how
test_boot_heap.py measures the heap the config release frees here). The port has no host
filesystem: firmware/, tests/firmware/ and tests/vectors/ are copied into its in-memory one
at the same relative places, so firmware_rig.find_file finds firmware/node.json and
tests/vectors/frames.json, and /tmp is writable.
"""
from __future__ import annotations

import importlib.util
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RUN_WASM = ROOT / "tests" / "wasm" / "run_wasm.mjs"
WASM_PKG = ROOT / "node_modules" / "@micropython" / "micropython-webassembly-pyscript"
NODE = shutil.which("node")
MOUNTS = ("firmware", "tests/firmware", "tests/vectors")  # host dir (from ROOT) = /repo/<dir>

def _runner():
    spec = importlib.util.spec_from_file_location("run_micropython", ROOT / "tests" / "run_micropython.py")
    rm = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rm)
    return rm


RM = _runner()
FILES = RM.discover([])


def run_steps(script_text: str, tmp_path: Path, timeout: float = 180) -> subprocess.CompletedProcess:
    """Run a STEP_DRIVER script on the port, its `_step` called from Node.js until done."""
    # Not a skip: without the 32-bit port these runs are missing, and that is a failure.
    assert NODE, "node (Node.js) not found on PATH"
    assert WASM_PKG.exists(), f"{WASM_PKG} missing: run `make test` (npm ci installs it)"
    script = tmp_path / "main.py"
    script.write_text(script_text)
    mounts = [f"{ROOT / d}=/repo/{d}" for d in MOUNTS]
    return subprocess.run([NODE, str(RUN_WASM), "--heap", str(4 << 20), "--step", "_step", *mounts, str(script)],
                          capture_output=True, text=True, timeout=timeout)


def test_every_micropython_test_file_is_run_here():
    assert {f.stem for f in FILES} >= {"test_alloc", "test_boot_heap", "test_config", "test_frames",
                                       "test_node", "test_rsens"}


# A generator test that needs the driver's collection between its steps: 64 KB freed.
FREES = """
import gc
BIG = [bytearray(65536), bytearray(65536)]
def _drop(i):
    BIG[i] = None
def test_inline_collect_frees():
    a = gc.mem_alloc()
    _drop(0)
    gc.collect()
    b = gc.mem_alloc()
    print("INLINE", a - b)
def test_steps_free():
    def steps():
        yield
        a = gc.mem_alloc()
        _drop(1)
        yield
        b = gc.mem_alloc()
        print("FREED", a - b)
        assert a - b >= 65536, a - b
    return steps()
"""


def test_the_step_driver_collects_between_steps_and_a_script_does_not(tmp_path):
    """Why the wasm runs go step by step: inside one script gc.collect() frees nothing here,
    between two steps called from Node.js it does."""
    d = tmp_path / "m"
    d.mkdir()
    (d / "test_frees.py").write_text(FREES)
    script = tmp_path / "main.py"
    script.write_text(RM.STEP_DRIVER % (RM.TAG, "test_frees"))
    r = subprocess.run([NODE, str(RUN_WASM), "--heap", str(4 << 20), "--step", "_step", f"{d}=/m", str(script)],
                       capture_output=True, text=True, timeout=60)
    results, finished, _ = RM._parse(r.stdout)
    assert finished and all(ok for _, ok, _ in results) and len(results) == 2, r.stdout + r.stderr
    assert int(r.stdout.split("INLINE ")[1].split()[0]) < 1024, r.stdout  # nothing collected inline
    # and the same steps as one script (DRIVER: its collections inside the script) fail here
    script.write_text(RM.DRIVER % (RM.TAG, "test_frees"))
    r = subprocess.run([NODE, str(RUN_WASM), "--heap", str(4 << 20), f"{d}=/m", str(script)],
                       capture_output=True, text=True, timeout=60)
    results, finished, _ = RM._parse(r.stdout)
    assert finished and dict((n, ok) for n, ok, _ in results)["test_steps_free"] is False, r.stdout


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.stem)
def test_firmware_file_passes_on_the_32_bit_wasm_port(path, tmp_path):
    r = run_steps(RM.STEP_DRIVER % (RM.TAG, path.stem), tmp_path)
    out = r.stdout + r.stderr
    results, finished, import_failed = RM._parse(r.stdout)
    assert not import_failed and finished and r.returncode == 0, out
    assert results, out
    failed = [(n, detail) for n, ok, detail in results if not ok]
    assert not failed, out
