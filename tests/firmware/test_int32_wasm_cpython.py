"""32-bit int safety of the hot path, proven on the official 32-bit MicroPython (WebAssembly).

The x86-64 unix port keeps ints up to 2**62 on the stack, so an intermediate
that overflows a 32-bit MCU's small int (+-2**30) goes unseen there. The
WebAssembly port is a real 32-bit build (sys.maxsize == 2**31-1): such an int
allocates, and heap_lock() turns the allocation into MemoryError. The same
test module that proves zero allocations on the unix port (test_alloc.py)
runs here, plus more random seeds, plus a deliberately overflowing variant of
the Node that this machinery must catch while the unix port cannot.
"""
from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "firmware"
TESTS_FW = ROOT / "tests" / "firmware"
RUN_WASM = ROOT / "tests" / "wasm" / "run_wasm.mjs"
WASM_PKG = ROOT / "node_modules" / "@micropython" / "micropython-webassembly-pyscript"
MICROPYTHON = Path(sys.executable).parent / "micropython"
NODE = shutil.which("node")


# Wraps the real Node: after each real sample, a product of two ~2**20 values,
# shifted back into range. Harmless on x86-64, an allocation on a 32-bit MCU.
OVERFLOW_NODE = """
from ropenode.node import Node as _Node
class Node(_Node):
    def __init__(self, cfg):
        _Node.__init__(self, cfg)
        self.overflow_probe = 0  # the attribute exists before the locked run

    def sample(self, rec):
        ready = _Node.sample(self, rec)
        self.overflow_probe = ((rec[0] | 0x1000) << 8) * ((rec[1] | 0x1000) << 8) >> 30
        return ready
"""

# Make test_alloc build the overflowing variant instead of the real Node.
USE_OVERFLOW_NODE = """
import sys, overflow_node
import ropenode.node
ropenode.node.Node = overflow_node.Node
"""


def run_wasm(script: str, tmp_path: Path, extra: dict[str, str] | None = None,
             timeout_s: float = 240) -> subprocess.CompletedProcess:
    """Run script on wasm MicroPython with firmware/ at /fw and tests/firmware at /tf."""
    # Not a skip: without the 32-bit port the proof is missing, and that is a failure.
    assert NODE, "node (Node.js) not found on PATH"
    assert WASM_PKG.exists(), f"{WASM_PKG} missing: run `make test` (npm ci installs it)"
    mounts = [f"{FIRMWARE}=/fw", f"{TESTS_FW}=/tf"]
    if extra:
        d = tmp_path / "extra"
        d.mkdir()
        for name, src in extra.items():
            (d / name).write_text(src)
        mounts.append(f"{d}=/extra")
    (tmp_path / "main.py").write_text(script)
    return subprocess.run([NODE, str(RUN_WASM), "--heap", str(4 << 20), *mounts, str(tmp_path / "main.py")],
                          capture_output=True, text=True, timeout=timeout_s)


def driver_script(module: str, prelude: str = ""):
    """(script, runner module): the unix runner's driver and PASS/FAIL protocol, on wasm."""
    spec = importlib.util.spec_from_file_location("run_micropython", ROOT / "tests" / "run_micropython.py")
    rm = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rm)
    return prelude + rm.DRIVER % (rm.TAG, module), rm


def test_wasm_port_is_32_bit_and_heap_lock_catches_big_ints(tmp_path):
    r = run_wasm(
        "import sys, micropython\n"
        "print('maxsize', sys.maxsize)\n"
        "def f(a, b):\n"
        "    micropython.heap_lock()\n"
        "    try:\n"
        "        c = a * b\n"
        "        r = 'small'\n"
        "    except MemoryError:\n"
        "        r = 'alloc'\n"
        "    micropython.heap_unlock()\n"
        "    return r\n"
        "print('2**30-1', f((1 << 30) - 1, 1))\n"
        "print('2**30', f(1 << 15, 1 << 15))\n"
        "print('-2**30', f(-(1 << 15), 1 << 15))\n"
        "print('2**40', f(1 << 20, 1 << 20))\n", tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["maxsize", str(2**31 - 1), "2**30-1", "small", "2**30", "alloc",
                                "-2**30", "small", "2**40", "alloc"]


def test_hot_path_allocation_free_on_32_bit(tmp_path):
    script, rm = driver_script("test_alloc")
    r = run_wasm(script, tmp_path)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out
    results, finished, import_failed = rm._parse(r.stdout)
    assert finished and not import_failed, out
    failed = [n for n, ok, _ in results if not ok]
    assert not failed, out
    assert {"test_sample_is_allocation_free_over_1000_samples", "test_sample_with_frames_between_windows",
            "test_heap_lock_catches_an_allocation", "test_frame_crc32_is_allocation_free"} <= {
        n for n, ok, _ in results if ok}


# The textbook CRC-32 with a 32-bit register: right on CPython, a long int on a 32-bit port.
NAIVE_CRC32 = """
import ropenode.crc32 as _c
_T = [0] * 256
for _i in range(256):
    _x = _i
    for _ in range(8):
        _x = (_x >> 1) ^ 0xEDB88320 if _x & 1 else _x >> 1
    _T[_i] = _x
def crc32_into(buf, n):
    c = 0xFFFFFFFF
    for k in range(n):
        c = (c >> 8) ^ _T[(c ^ buf[k]) & 0xFF]
    c ^= 0xFFFFFFFF
    for j in range(4):
        buf[n + j] = (c >> (8 * j)) & 0xFF
    return n + 4
_c.crc32_into = crc32_into
"""


def test_a_32_bit_register_crc_is_caught_on_32_bit(tmp_path):
    """Why ropenode.crc32 works in 16-bit halves: the textbook 32-bit register allocates on
    a 32-bit port, and test_frame_crc32_is_allocation_free fails on it there."""
    script, rm = driver_script("test_alloc", "import naive_crc32\n")
    r = run_wasm(script, tmp_path, extra={"naive_crc32.py": NAIVE_CRC32})
    results, finished, _ = rm._parse(r.stdout)
    assert finished, r.stdout + r.stderr
    verdict = {n: ok for n, ok, _ in results}
    assert verdict["test_frame_crc32_is_allocation_free"] is False, r.stdout
    assert "crc32_into allocated on frame 0" in r.stdout


def test_random_streams_allocation_free_on_32_bit(tmp_path):
    r = run_wasm(
        "import array, test_alloc as t, ropenode.node\n"
        "print('kernel', ropenode.node.K.__name__)\n"
        "node, ropes, chans = t.build_node()\n"
        "w = 2 * ropes + 4\n"
        "rec = array.array('H', bytes(2 * w))\n"
        "for seed in (3, 5, 11, 2024):\n"
        "    recs = t.hot_path_records(ropes, chans, 1200, seed)\n"
        "    ready, bad = t._sample_locked(node, recs, 0, 1200, w, rec)\n"
        "    print('seed', seed, 'windows', ready, 'bad', bad)\n"
        "    assert bad < 0, list(recs[bad * w:bad * w + w])\n", tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "kernel ropenode.kernel\n" in r.stdout  # no native emitter here: the plain kernel runs
    assert r.stdout.count("bad -1") == 4


def test_overflowing_variant_is_caught_on_32_bit(tmp_path):
    """The check can fail: a 2**40 intermediate makes the 32-bit proof fail on record 0."""
    script, rm = driver_script("test_alloc", USE_OVERFLOW_NODE)
    r = run_wasm(script, tmp_path, extra={"overflow_node.py": OVERFLOW_NODE})
    results, finished, _ = rm._parse(r.stdout)
    assert finished, r.stdout + r.stderr
    verdict = {n: ok for n, ok, _ in results}
    assert verdict["test_sample_is_allocation_free_over_1000_samples"] is False, r.stdout
    assert "allocated on record 0" in r.stdout


def test_overflowing_variant_passes_unseen_on_x86_64_unix_port(tmp_path):
    """Why the wasm check exists: the 64-bit unix port does not see the same overflow."""
    d = tmp_path / "extra"
    d.mkdir()
    (d / "overflow_node.py").write_text(OVERFLOW_NODE)
    code = ("import sys\n" + USE_OVERFLOW_NODE + "import test_alloc\n"
            "test_alloc.test_sample_is_allocation_free_over_1000_samples()\nprint('unseen')\n")
    env = dict(os.environ, MICROPYPATH=os.pathsep.join([str(FIRMWARE), str(TESTS_FW), str(d)]))
    r = subprocess.run([str(MICROPYTHON), "-c", code], cwd=ROOT, env=env, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0 and "unseen" in r.stdout, r.stdout + r.stderr
