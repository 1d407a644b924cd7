"""Integer-only firmware, proven statically and by AST range instrumentation under CPython.

1. Float-free scan: no firmware module contains a float literal, true division
   `/`, `float(...)` or `import math`.
2. Range instrumentation: every firmware module is re-compiled with each
   arithmetic result (BinOp, UnaryOp, and the target after an AugAssign)
   wrapped in a check; the hot path (Node.sample) then runs over the same
   extreme/fault/random streams as test_alloc.py. Any int outside
   [-2**30, 2**30) -- a non-small int on a 32-bit MicroPython, which would
   allocate -- or any float fails, naming file and line. The frames it closes
   are packed under the check too, late in the node's life (seq and time_ms
   are u32 on the wire). This bounds every
   intermediate, including those in code the wasm run may not reach by chance,
   and it works for viper functions too (their decorators are no-ops here).
"""
from __future__ import annotations

import ast
import importlib.abc
import importlib.util
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "firmware"
SMALL_LO, SMALL_HI = -(1 << 30), 1 << 30
SOURCES = sorted(FIRMWARE.rglob("*.py"))


# --- 1. float-free scan -------------------------------------------------------

def float_uses(src: str) -> list[tuple[int, str]]:
    """(line, what) for each float literal, true division, float() call or math import."""
    found = []
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.Constant) and isinstance(node.value, (float, complex)):
            found.append((node.lineno, f"float literal {node.value!r}"))
        elif isinstance(node, (ast.BinOp, ast.AugAssign)) and isinstance(node.op, ast.Div):
            found.append((node.lineno, "true division '/'"))
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "float":
            found.append((node.lineno, "float() call"))
        elif isinstance(node, ast.Import) and any(a.name == "math" for a in node.names):
            found.append((node.lineno, "import math"))
        elif isinstance(node, ast.ImportFrom) and node.module == "math":
            found.append((node.lineno, "from math import"))
    return sorted(found)


def test_no_firmware_module_uses_floats():
    bad = [f"{p.relative_to(ROOT)}:{line}: {what}"
           for p in SOURCES for line, what in float_uses(p.read_text())]
    assert not bad, "\n".join(bad)


def test_float_scan_finds_floats():
    src = "import math\nx = 1.5\ny = 3 / 2\ny /= 2\nz = float(3)\n"
    assert [ln for ln, _ in float_uses(src)] == [1, 2, 3, 4, 5]
    assert float_uses("a = 7 // 2\nb = a >> 1\nc = 'x/y'\n") == []


# --- 2. range instrumentation -------------------------------------------------

class RangeViolation(AssertionError):
    pass


class RangeMonitor:
    """Receives every checked arithmetic result while armed; keeps the extremes."""

    def __init__(self):
        self.armed = False
        self.checked = 0
        self.peak: dict[str, int] = {}  # location -> largest |int| seen while armed

    def __call__(self, value, loc):
        if self.armed:
            t = type(value)
            if t is int:
                self.checked += 1
                if not SMALL_LO <= value < SMALL_HI:
                    raise RangeViolation(f"{loc}: intermediate {value} is outside +-2**30")
                a = -value if value < 0 else value
                if a > self.peak.get(loc, -1):
                    self.peak[loc] = a
            elif t is float:
                raise RangeViolation(f"{loc}: float {value!r} on the hot path")
        return value


class _Instrument(ast.NodeTransformer):
    def __init__(self, filename: str):
        self.filename = filename

    def _wrap(self, node: ast.expr) -> ast.expr:
        loc = f"{self.filename}:{node.lineno}:{node.col_offset}"
        call = ast.Call(func=ast.Name("__rangecheck__", ast.Load()), args=[node, ast.Constant(loc)], keywords=[])
        return ast.copy_location(call, node)

    def visit_BinOp(self, node):
        self.generic_visit(node)
        return self._wrap(node)

    def visit_UnaryOp(self, node):
        self.generic_visit(node)
        return self._wrap(node) if isinstance(node.op, (ast.USub, ast.Invert)) else node

    def visit_AugAssign(self, node):
        self.generic_visit(node)
        load = _as_load(node.target)
        check = ast.Expr(self._wrap(ast.copy_location(load, node)))
        return [node, ast.copy_location(check, node)]


def _as_load(target: ast.expr) -> ast.expr:
    t = ast.parse(ast.unparse(target), mode="eval").body
    return t


def instrument(src: str, filename: str) -> ast.Module:
    tree = _Instrument(filename).visit(ast.parse(src, filename))
    return ast.fix_missing_locations(tree)


class _Finder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports `ropenode*` from firmware/ through the instrumenting compiler."""

    def __init__(self, monitor: RangeMonitor):
        self.monitor = monitor

    def find_spec(self, fullname, path, target=None):
        if fullname != "ropenode" and not fullname.startswith("ropenode."):
            return None
        rel = Path(*fullname.split("."))
        pkg = FIRMWARE / rel / "__init__.py"
        mod = FIRMWARE / rel.with_suffix(".py")
        if pkg.exists():
            return importlib.util.spec_from_file_location(fullname, pkg, loader=self,
                                                          submodule_search_locations=[str(pkg.parent)])
        if mod.exists():
            return importlib.util.spec_from_file_location(fullname, mod, loader=self)
        return None

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        path = Path(module.__spec__.origin)
        module.__dict__["__rangecheck__"] = self.monitor
        code = compile(instrument(path.read_text(), str(path.relative_to(ROOT))), str(path), "exec")
        exec(code, module.__dict__)


@contextmanager
def instrumented_firmware():
    """Within: `ropenode.*` and test_alloc are instrumented copies; the real ones come back after."""
    monitor = RangeMonitor()
    saved = {k: v for k, v in sys.modules.items() if k == "ropenode" or k.startswith("ropenode.")
             or k == "test_alloc"}
    for k in saved:
        del sys.modules[k]
    finder = _Finder(monitor)
    sys.meta_path.insert(0, finder)
    sys.path.insert(0, str(Path(__file__).parent))
    try:
        yield monitor
    finally:
        sys.meta_path.remove(finder)
        sys.path.remove(str(Path(__file__).parent))
        for k in [k for k in sys.modules if k == "ropenode" or k.startswith("ropenode.") or k == "test_alloc"]:
            del sys.modules[k]
        sys.modules.update(saved)


def run_armed(monitor: RangeMonitor, seeds=(1, 7, 99), count=1600) -> int:
    """Node.sample over the test_alloc streams with the range check armed; returns samples run.

    The shipped config with each seed, then the oil-temperature-fitted 4-rope
    and 1-rope variants (temperature words across the whole u16 range), and the
    largest hydraulic compliance the node accepts, its noise following over its whole
    range from the smallest and the largest level (and slide following over the largest
    and the smallest span).
    """
    import array

    import test_alloc
    from ropenode import layout
    from ropenode.node import K
    runs = [(None, seed) for seed in seeds] + [
        (test_alloc.variant_doc(temp_fitted=True, stroke=True), 5), (test_alloc.variant_doc(ropes=1, temp_fitted=True), 6),
        (test_alloc.variant_doc(compliance=True), 8),
        (test_alloc.variant_doc(compliance=True, noise_ref_q6=1 << 18, slide_span_q8um=1, stroke=True), 9)]
    done = 0
    for doc, seed in runs:
        node, ropes, chans = test_alloc.build_node(doc)
        # frames late in the node's life: 49.7 days of node time (sec * 1000 passes 2**32)
        # and the last boot before the 12-bit counter wraps, near a frame-count wrap
        node.S[K.SEC] = 4294960
        node.frame_seq.boot, node.frame_seq.count = 4095, (1 << 20) - 2
        w = 2 * ropes + 4
        rec = array.array("H", bytes(2 * w))
        buf = bytearray(layout.MAX_WIRE_LEN)
        recs = test_alloc.hot_path_records(ropes, chans, count, seed)
        if doc is not None:
            for k in range(count):
                recs[k * w + 2 * ropes + 1] = (k * 53) & 0xFFFF if k % 3 else 9600 + (k * 37) % 38400
        for k in range(count):
            rec[:] = recs[k * w:(k + 1) * w]
            monitor.armed = True
            try:
                ready = node.sample(rec)
                if ready:
                    node.frame_into(buf)  # per frame: seq and time as 16-bit halves
            except RangeViolation as e:
                raise RangeViolation(f"{e} (record {k}, seed {seed}: {list(rec)})") from None
            finally:
                monitor.armed = False
            assert ready is True or ready is False
            done += 1
    return done


def test_hot_path_intermediates_stay_within_small_int_range():
    with instrumented_firmware() as monitor:
        n = run_armed(monitor)
    assert n == 7 * 1600
    assert monitor.checked > 10 * n  # the hot path really went through instrumented arithmetic
    assert any("crc32.py" in loc for loc in monitor.peak)  # frames were sealed under the check: CRC-32 too
    worst = max(monitor.peak.items(), key=lambda kv: kv[1])
    print(f"largest hot-path intermediate: {worst[1]} ({worst[1].bit_length()} bits) at {worst[0]}")


def test_position_sums_of_the_longest_window_stay_small():
    """The longest window config.py allows (1000 samples: sample_hz 1000, frame_hz 1), every
    piston held at the largest position a config can give (its channel's fault limit moved
    to within 2**25 um/256, each sign): the window's position sum (about 2**27) and its
    mean stay within +-2**30, and the mean is that position in 0.1 mm."""
    import array

    kernel_src = (Path(__file__).parents[2] / "firmware" / "ropenode" / "kernel.py").read_text()
    line = next(k + 1 for k, t in enumerate(kernel_src.splitlines()) if "S[_XSUM + i] +=" in t)
    with instrumented_firmware() as monitor:
        import test_alloc
        from ropenode.config import parse_node
        from ropenode.node import K, Node
        for sign in (1, -1):
            nd = test_alloc.load_node_json()["node"]
            nd.update(sample_hz=1000, frame_hz=1)
            nd["shaft"].update(max_pulses_per_sample=1, mm_per_pulse_q16=500000)
            for key in ("travel_lo_q8um", "stroke_lo_q8um", "stroke_hi_q8um", "travel_hi_q8um"):
                nd.pop(key, None)  # no travel limit: the positions go to their largest
            for ch in nd["displacement"]:
                j = "fault_hi_counts" if sign > 0 else "fault_lo_counts"
                x = ch["q8um_at_lo"] + (((ch[j] - ch["counts_lo"]) * ch["q8um_mul"]) >> ch["q8um_shift"])
                ch["q8um_at_lo"] += sign * ((1 << 25) - 1) - x
            cfg = parse_node(nd)
            node = Node(cfg)
            assert node.window_len == 1000
            d = cfg.displacement
            rec = array.array("H", [30000] * 4 + [d[1 + (sign > 0)]] * 4 + [40000, 0xFFFF, 0, 0])
            closed = 0
            monitor.armed = True
            try:
                for _ in range(2000):
                    closed += node.sample(rec)
            finally:
                monitor.armed = False
            assert closed == 2
            want = sign * round(((1 << 25) - 1) / 256 / 100)  # 0.1 mm
            assert node.rope(K.OUT_POS) == [want] * 4, (node.rope(K.OUT_POS), want)
    peak = max(v for loc, v in monitor.peak.items() if loc.startswith(f"firmware/ropenode/kernel.py:{line}:"))
    assert 1 << 26 < peak < 1 << 28, peak


def test_crc32_intermediates_stay_within_16_bits():
    """The frame's CRC-32 (ropenode.crc32, 16-bit halves) over random frames and runs of
    0x00 and 0xFF: binascii.crc32's value, and no intermediate reaches 2**16."""
    import binascii
    import random

    rng = random.Random(5)
    cases = [bytes(64), b"\xff" * 64, bytes(range(256))] + [rng.randbytes(rng.randint(0, 64)) for _ in range(2000)]
    with instrumented_firmware() as monitor:
        from ropenode.crc32 import crc32_into
        monitor.armed = True
        try:
            for data in cases:
                buf = bytearray(data) + bytearray(4)
                crc32_into(buf, len(data))
                assert int.from_bytes(buf[-4:], "little") == binascii.crc32(data)
        finally:
            monitor.armed = False
    peaks = {loc: v for loc, v in monitor.peak.items() if "crc32.py" in loc}
    assert len(peaks) >= 8 and max(peaks.values()) < 1 << 16, peaks


def test_range_check_catches_an_overflowing_product():
    """The check can fail: a product of two 2**20 values is reported with its line."""
    monitor = RangeMonitor()
    src = "def f(a, b):\n    c = a + 1\n    c += b\n    return (a * b) >> 30\n"
    ns = {"__rangecheck__": monitor}
    exec(compile(instrument(src, "probe.py"), "probe.py", "exec"), ns)
    monitor.armed = True
    assert ns["f"](1 << 10, 1 << 10) == 0
    with pytest.raises(RangeViolation, match="probe.py:4"):
        ns["f"](1 << 20, 1 << 20)
    with pytest.raises(RangeViolation, match="probe.py:3"):  # the AugAssign result
        ns["f"](1 << 29, (1 << 29) + 5)
    with pytest.raises(RangeViolation, match="float"):
        ns["f"](0.5, 2)
