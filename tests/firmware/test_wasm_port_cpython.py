"""The firmware test files run on the official 32-bit MicroPython (WebAssembly port) too.

Every file tests/run_micropython.py runs under the unix port (tests/firmware/test_*.py not
named *_cpython.py) runs here through Node.js (tests/wasm/run_wasm.mjs), with the same
driver and PASS/FAIL protocol, except those in NOT_ON_WASM, each with its reason. The port
has no host filesystem: firmware/, tests/firmware/ and tests/vectors/ are copied into its
in-memory one at the same relative places, so fwtest_util.find_file finds
firmware/node.json and tests/vectors/frames.json, and /tmp is writable.
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

NOT_ON_WASM = {
    # Already run on this port, with more seeds and checks that can fail, by
    # test_int32_wasm_cpython.py (test_hot_path_allocation_free_on_32_bit).
    "test_alloc": "run by test_int32_wasm_cpython.py",
    # It measures the heap the config validator's release frees (gc.mem_alloc after
    # gc.collect). The port's gc.collect() frees nothing inside a running script: it grows
    # the heap instead and collects only between top-level calls.
    "test_boot_heap": "gc.collect() frees nothing inside a running script on this port",
}


def _runner():
    spec = importlib.util.spec_from_file_location("run_micropython", ROOT / "tests" / "run_micropython.py")
    rm = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rm)
    return rm


RM = _runner()
FILES = RM.discover([])


def test_the_files_left_out_exist():
    assert set(NOT_ON_WASM) <= {f.stem for f in FILES}


@pytest.mark.parametrize("path", [f for f in FILES if f.stem not in NOT_ON_WASM], ids=lambda p: p.stem)
def test_firmware_file_passes_on_the_32_bit_wasm_port(path, tmp_path):
    # Not a skip: without the 32-bit port these runs are missing, and that is a failure.
    assert NODE, "node (Node.js) not found on PATH"
    assert WASM_PKG.exists(), f"{WASM_PKG} missing: run `make test` (npm ci installs it)"
    script = tmp_path / "main.py"
    script.write_text(RM.DRIVER % (RM.TAG, path.stem))
    mounts = [f"{ROOT / d}=/repo/{d}" for d in MOUNTS]
    r = subprocess.run([NODE, str(RUN_WASM), "--heap", str(4 << 20), *mounts, str(script)],
                       capture_output=True, text=True, timeout=180)
    out = r.stdout + r.stderr
    results, finished, import_failed = RM._parse(r.stdout)
    assert not import_failed and finished and r.returncode == 0, out
    assert results, out
    failed = [(n, detail) for n, ok, detail in results if not ok]
    assert not failed, out
