"""The firmware on 32-bit MicroPython with a native emitter: i386 and ARM Thumb-2.

The unix port is 64-bit (a viper int is 64 bits there) and the WebAssembly port has no
native emitter, so neither runs the viper kernel as a 32-bit MCU does: viper ints wrapping
modulo 2**32, the generated sign extension `(x ^ 2**31) - 2**31` the identity, floor
division, shifts and ptr16/ptr32 loads in 32-bit machine code. `make test` builds two such
MicroPythons (tools/mpy32/build.sh, into .cache/mpy32/): i386 (gcc -m32, the x86 emitter,
run natively) and ARMv7 Thumb-2 (the Thumb emitter, the one Cortex-M boards use, run under
qemu-user). Here, on both:

- every firmware test file tests/run_micropython.py runs (found by its discovery, so a new
  file runs here too), with its driver and PASS/FAIL protocol;
- the viper kernel is bit-identical to the plain one, sample after sample (state array S,
  ready flags, frames): on test_kernel_viper_cpython's streams (test_alloc's fault, rail and
  shock records and random walks, with the shipped config and its variants), on
  streams_cpython's random streams (the compensation tests' streams, with NAMUR faults), on
  the drawn-wind vector of tests/vectors, and on fuzzed configs (every scalar and channel
  field drawn at its limits or anywhere in its range, kept where config.parse accepts it)
  fed extreme sensor words (rails, fault thresholds and one count either side, full-range
  noise, speed-counter jumps);
- a kernel generated without sign extension, harmless on 32 bits, must still be equal there
  (it is caught on the unix port by test_kernel_viper_cpython).
Not skips: without the builds (make .cache/mpy32/.built) these tests fail.
"""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "firmware"
TESTS_FW = ROOT / "tests" / "firmware"
MPY32 = ROOT / ".cache" / "mpy32"
EXES = {"x86": MPY32 / "x86" / "micropython", "thumb": MPY32 / "thumb" / "micropython-qemu"}
ARCHS = list(EXES)

sys.path.insert(0, str(ROOT / "tools"))
import gen_kernel_viper as gen  # noqa: E402

from ropemon.firmware import install_shim, node_module  # noqa: E402

def _runner():
    spec = importlib.util.spec_from_file_location("run_micropython", ROOT / "tests" / "run_micropython.py")
    rm = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rm)
    return rm


RM = _runner()
FILES = RM.discover([])


def _exe(arch: str) -> str:
    exe = EXES[arch]
    assert exe.exists(), f"{exe} missing: run `make .cache/mpy32/.built` (make test builds it)"
    return str(exe)


def run(arch: str, script: str, tmp_path: Path, extra_path: list[Path] | None = None, timeout: float = 300):
    path = tmp_path / f"script_{arch}.py"
    path.write_text(script)
    env = dict(os.environ, MICROPYPATH=os.pathsep.join(str(p) for p in [FIRMWARE, TESTS_FW, *(extra_path or [])]))
    return subprocess.run([_exe(arch), "-X", "heapsize=8M", str(path)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout)


def test_every_micropython_test_file_is_run_here():
    assert {f.stem for f in FILES} >= {"test_alloc", "test_boot_heap", "test_config", "test_frames",
                                       "test_node", "test_rsens"}


@pytest.mark.parametrize("arch", ARCHS)
def test_build_is_32_bit_and_viper_is_machine_code(arch, tmp_path):
    r = run(arch, r'''
import sys, array, micropython
from ropenode import node as N
assert sys.maxsize == 2**31 - 1, sys.maxsize
assert N.K.__name__.endswith("kernel_viper"), N.K.__name__  # the Node picks viper here

@micropython.viper
def mul(a: int, b: int) -> int:
    return a * b

@micropython.viper
def ops(buf, i: int, d: int) -> int:
    p = ptr32(buf)
    h = ptr16(buf)
    x = p[i]
    return (x // d) + (x >> 3) + h[2 * i]

a = array.array("i", [-7, 2**31 - 1, -2**30])
print("WRAP", mul(1 << 20, 1 << 12), mul(2**16, 2**15), mul(-7, 3))
print("OPS", ops(a, 0, 2), ops(a, 0, -2), ops(a, 1, 1 << 30), ops(a, 2, 3))
''', tmp_path)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out
    # 2**32 wraps to 0 and 2**31 to -2**31: a 32-bit viper int (64-bit on the unix port)
    assert "WRAP 0 -2147483648 -21" in out, out
    # ptr32 loads sign-extend; // floors; >> is arithmetic; ptr16 reads the low half
    # -7//2=-4, -7>>3=-1, 0xFFF9=65529; -7//-2=3; (2**31-1)//2**30=1, >>3=268435455, 0xFFFF
    # -2**30//3 = -357913942, >>3 = -134217728, low half 0.
    # (Not -2**31: viper's // calls mp_small_int_floor_divide, which moves a negative
    # numerator by 1 - d before dividing; within d - 1 of -2**31 that wraps on 32 bits and
    # -2**31 // 3 gives +715827882 on both builds. The kernel stays within +-2**30,
    # test_int32_ast_cpython.py, so it never gets there.)
    assert "OPS 65524 65531 268500991 -492131670" in out, out


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.stem)
@pytest.mark.parametrize("arch", ARCHS)
def test_firmware_file_passes_on_32_bit_native(arch, path):
    results, out = RM.run_file(_exe(arch), path)
    assert results, out
    failed = [(n, detail) for n, ok, detail in results if not ok]
    assert not failed, out
    assert any(n.startswith("test_") for n, ok, _ in results), out


# ---- viper == plain, on the 32-bit builds ----

def _kernel_viper_test():
    spec = importlib.util.spec_from_file_location("tkv", TESTS_FW / "test_kernel_viper_cpython.py")
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m


SAMPLES = {"x86": 10000, "thumb": 2000}  # per walk; the Thumb build runs emulated


@pytest.mark.parametrize("arch", ARCHS)
def test_viper_equals_plain_on_the_viper_tests_streams(arch, tmp_path):
    script = _kernel_viper_test().COMPARE.replace("STEP_MODULE", "ropenode.kernel_viper") \
        .replace("SAMPLES", str(SAMPLES[arch]))
    r = run(arch, script, tmp_path, timeout=600)
    out = r.stdout + r.stderr
    assert r.returncode == 0 and "MISMATCH" not in out, out
    assert out.count("EQUAL") == 10 and "TOTAL %d" % (5 * (2400 + SAMPLES[arch])) in out, out


@pytest.mark.parametrize("arch", ARCHS)
def test_kernel_without_sign_extension_is_equal_on_32_bit(arch, tmp_path):
    """The sign extension is the identity on 32 bits: the variant the unix port catches
    (test_kernel_viper_cpython) must be bit-identical here, so these builds really are 32-bit
    viper (and the unix port's catch is about its 64-bit ints, not a kernel bug)."""
    d = tmp_path / "extra"
    d.mkdir()
    (d / "kernel_noext.py").write_text(gen.generate(gen.KERNEL.read_text(), sign_extend=False))
    script = _kernel_viper_test().COMPARE.replace("STEP_MODULE", "kernel_noext").replace("SAMPLES", "300")
    r = run(arch, script, tmp_path, extra_path=[d])
    out = r.stdout + r.stderr
    assert r.returncode == 0 and "MISMATCH" not in out and out.count("EQUAL") == 10, out


# Runs on the device: each job a config file and a raw little-endian uint16 record file.
JOBS_SCRIPT = r'''
import array, json
from ropenode import kernel, kernel_viper, node as N
from ropenode.config import parse
from ropenode.layout import MAX_WIRE_LEN
assert N.K is kernel_viper, N.K.__name__
for tag, cfg_path, rec_path in JOBS:
    with open(cfg_path) as f:
        cfg = parse(json.load(f))
    with open(rec_path, "rb") as f:
        recs = array.array("H", f.read())
    w = 2 * cfg.ropes + 4
    a = N.Node(cfg, step=kernel_viper.step)
    b = N.Node(cfg, step=kernel.step)
    rec = array.array("H", bytes(2 * w))
    ba = bytearray(MAX_WIRE_LEN)
    bb = bytearray(MAX_WIRE_LEN)
    count = len(recs) // w
    frames = 0
    ok = True
    for k in range(count):
        rec[:] = recs[k * w:(k + 1) * w]
        ra = a.sample(rec)
        rb = b.sample(rec)
        if ra != rb or bytes(a.S) != bytes(b.S):
            diff = [j for j in range(len(a.S)) if a.S[j] != b.S[j]]
            print("MISMATCH", tag, "record", k, list(rec), "S", diff[:8],
                  [a.S[j] for j in diff[:8]], [b.S[j] for j in diff[:8]])
            ok = False
            break
        if ra:
            na = a.frame_into(ba)
            nb = b.frame_into(bb)
            if ba[:na] != bb[:nb]:
                print("MISMATCH", tag, "frame at record", k)
                ok = False
                break
            frames += 1
    if ok:
        print("EQUAL", tag, count, frames)
'''


def _write_job(tmp: Path, tag: str, doc: dict, recs: np.ndarray) -> tuple[str, str, str]:
    c = tmp / f"{tag}.json"
    c.write_text(json.dumps(doc))
    r = tmp / f"{tag}.u16"
    r.write_bytes(np.ascontiguousarray(recs, dtype="<u2").tobytes())
    return tag, str(c), str(r)


def _run_jobs(arch: str, tmp_path: Path, jobs: list[tuple[str, str, str]], timeout: float = 600):
    r = run(arch, "JOBS = %r\n" % (jobs,) + JOBS_SCRIPT, tmp_path, timeout=timeout)
    out = r.stdout + r.stderr
    assert r.returncode == 0 and "MISMATCH" not in out, out
    for tag, _, _ in jobs:
        assert f"EQUAL {tag} " in out, out
    return out


def _shipped() -> dict:
    return json.loads((FIRMWARE / "node.json").read_text())


@pytest.mark.parametrize("arch", ARCHS)
def test_viper_equals_plain_on_the_compensation_streams_and_the_drawn_wind(arch, tmp_path):
    from streams_cpython import random_stream

    doc = _shipped()
    secs = 40 if arch == "x86" else 8
    jobs = [_write_job(tmp_path, f"random{seed}{'f' if faults else ''}", doc,
                       random_stream(doc["physical"], secs, seed, faults=faults))
            for seed, faults in ((1, False), (2, True), (3, True))]
    vec = np.load(ROOT / "tests" / "vectors" / "drawn-wind-stroke-end.npz")
    jobs.append(_write_job(tmp_path, "drawn_wind", json.loads(str(vec["node_json"])), vec["records"]))
    _run_jobs(arch, tmp_path, jobs)


# ---- fuzzed legal configs and extreme sensor words ----

def _table(text: str):
    rows = []
    for line in text.strip().splitlines():
        parts = line.split()
        rows.append((parts[0], *map(int, parts[1:])))
    return rows


def _draw(rng, lo: int, hi: int, cur: int) -> int:
    k = rng.integers(0, 6)
    if k == 0:
        return lo
    if k == 1:
        return hi
    if k == 2:
        return int(rng.integers(lo, hi + 1))
    if k == 3:  # near the current value, within the range
        return int(min(max(cur + rng.integers(-3, 4) * max(abs(cur) // 4, 1), lo), hi))
    if k == 4:
        return min(lo + 1, hi)
    return max(hi - 1, lo)


def fuzz_config(seed: int, steps: int = 240) -> dict:
    """A legal node config: from the shipped one with 1..4 ropes, `steps` mutations of one
    scalar, channel or pressure-line field each, drawn at its limits, next to them or
    anywhere in its range; a mutation stays only if config.parse accepts the result (so the
    fields' cross-checks hold), and the config walks far from the shipped one."""
    install_shim()
    config = node_module("config")
    crc16 = node_module("crc16").crc16
    rng = np.random.default_rng(seed)
    doc = _shipped()
    nd = doc["node"]
    ropes = int(rng.integers(1, 5))
    nd["ropes"] = ropes
    for key in ("pressure", "displacement"):
        nd[key] = nd[key][:ropes]
    for key in ("v_um_s", "force_n"):
        nd["loss"][key] = nd["loss"][key][:ropes]
    for key in ("compliance_q", "area_q8", "play_q8um", "rest_play_q8um", "rest_q16um"):  # as test_alloc.variant_doc
        nd["friction"][key] = nd["friction"][key][:ropes]
    for key, _ in config._STROKE:  # the travel and stroke limits, per rope (absent: off)
        v = nd.get(key, _)
        nd[key] = (v if type(v) is list else [v] * 4)[:ropes]
    slots = []  # (dict, key, lo, hi)
    for name, lo, hi in _table(config._FIELDS):
        sec, _, key = name.rpartition(".")
        d = nd.get(sec) if sec else nd
        if isinstance(d, dict) and key in d and key not in ("node_id", "ropes", "sample_hz", "frame_hz"):
            slots.append((d, key, lo, hi))
    for chans, table in ((nd["pressure"], config._PRESSURE), (nd["displacement"], config._DISPLACEMENT)):
        for ch in chans:
            slots += [(ch, name, lo, hi) for name, lo, hi in _table(table)]
    for key, _ in config._STROKE:
        slots += [(nd[key], i, -config._LIMIT, config._LIMIT) for i in range(ropes)]
    for name, lo, hi, _ in _table(config._LINEAR):
        lin = nd["friction"][name]
        slots += [(lin, "at_0", lo, hi), (lin, "slope_mul", -(1 << 15), 1 << 15), (lin, "slope_shift", 0, 30)]

    def legal():
        doc["crc"] = crc16(config.canonical(nd))
        try:
            config.parse(doc)
        except config.ConfigError:
            return False
        return True

    assert legal(), "the shipped config cut to %d ropes is refused" % ropes
    kept = 0
    for _ in range(steps):
        d, key, lo, hi = slots[int(rng.integers(0, len(slots)))]
        old = d[key]
        d[key] = _draw(rng, lo, hi, old)
        if legal():
            kept += d[key] != old
        else:
            d[key] = old
    assert legal() and kept >= steps // 8, kept
    return doc


def extreme_records(doc: dict, count: int, seed: int) -> np.ndarray:
    """Sensor words at the edges: the rails, each channel's fault thresholds and one count
    either side, its 4 mA / lowest count, full-range noise, holds and big steps; the speed
    counter jumping by up to +-32767 and wrapping; battery, temperature and Hall words at random."""
    nd = doc["node"]
    n = nd["ropes"]
    w = 2 * n + 4
    rng = np.random.default_rng(seed)
    out = np.zeros((count, w), np.uint16)
    edges = []
    for ch, first in [(c, "counts_4ma") for c in nd["pressure"]] + [(c, "counts_lo") for c in nd["displacement"]]:
        e = {0, 1, 65534, 65535}
        for key in (first, "fault_lo_counts", "fault_hi_counts"):
            for d in (-1, 0, 1):
                e.add(min(max(ch[key] + d, 0), 65535))
        edges.append(np.array(sorted(e)))
    cur = np.array([int(rng.integers(0, 65536)) for _ in range(2 * n)])
    speed = 0
    for k in range(count):
        mode = (k // 97) % 4  # runs of edges, noise, holds, and slow walks
        for j in range(2 * n):
            r = rng.random()
            if mode == 0 or r < 0.05:
                cur[j] = rng.choice(edges[j])
            elif mode == 1:
                cur[j] = rng.integers(0, 65536)
            elif mode == 3:
                cur[j] = min(max(cur[j] + int(rng.integers(-300, 301)), 0), 65535)
        out[k, :2 * n] = cur
        out[k, 2 * n] = rng.choice([0, 65535, int(rng.integers(0, 65536))])
        out[k, 2 * n + 1] = rng.choice([0, 65535, int(rng.integers(0, 65536)), 0xFFFF])
        speed = (speed + int(rng.choice([0, 1, -1, 32767, -32768, int(rng.integers(-2000, 2001))]))) & 0xFFFF
        out[k, 2 * n + 2] = speed
        out[k, 2 * n + 3] = int(rng.random() < 0.02)
    return out


FUZZ = {"x86": (12, 4000), "thumb": (4, 1500)}  # configs, samples each


@pytest.mark.parametrize("arch", ARCHS)
def test_viper_equals_plain_on_fuzzed_configs_and_extreme_streams(arch, tmp_path):
    nconf, count = FUZZ[arch]
    jobs = []
    for i in range(nconf):
        doc = fuzz_config(1000 + i)
        jobs.append(_write_job(tmp_path, f"fuzz{i}r{doc['node']['ropes']}", doc, extreme_records(doc, count, 2000 + i)))
    _run_jobs(arch, tmp_path, jobs, timeout=900)


def _bench():
    spec = importlib.util.spec_from_file_location("mpy32_bench", ROOT / "tools" / "mpy32" / "bench.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


@pytest.mark.parametrize("arch", ["x64", "x86", "armv7m"])
def test_a_boards_boot_fits_a_96_kib_heap(arch, tmp_path):
    """A board's boot from .mpy (tools/mpy32/bench.py --least-heap's script: the config
    parsed and released, the Node and the front end's modules, 400 samples and frames)
    completes in a 96 KiB heap on the unix port and both 32-bit builds (each boots in every
    size from 68-87 KiB, docs/benchmarks.md). Taking the config's CRC over its canonical
    bytes built whole needed 155-202 KB."""
    bench = _bench()
    exe = next(e for e, a in bench.BUILDS.values() if a == arch)
    assert bench.boot_in(exe, arch, tmp_path)(96 * 1024)
