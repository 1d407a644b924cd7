"""The viper kernel is the plain kernel: generated from it, and bit-exact on the unix port.

Both builds come from one source, tools/kernel_src.py, whose helpers (`_q14mul`,
`_clamp`, `_divround`) tools/gen_kernel_viper.py expands inline: kernel.py must be
exactly that expansion, with no call left in its `step`; the source run as it is (its
helpers called, under CPython) must give the plain kernel's state bit for bit, every
helper call site reached; and the generator must refuse a helper call whose expansion
could mean something other than the call.
kernel_viper.py must be exactly what tools/gen_kernel_viper.py makes of kernel.py
(so the two cannot drift), and on the unix port (which has the native
emitter) the Node must pick it and produce, sample after sample, the same
state array S and the same frames as the plain kernel, over long random
streams: test_alloc's fault/rail/shock streams and random walks across the
full sensor ranges, with the shipped config and with variants (oil
temperature input, 1 and 3 ropes). The plain kernel's ranges are bounded by
test_int32_ast_cpython.py and its allocation-freedom on 32 bits by the wasm
run; with the same arithmetic, the viper kernel inherits both. A variant
generated without sign extension must be caught.
"""
from __future__ import annotations

import array
import ast
import importlib.util
import os
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import gen_kernel_viper as gen  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "firmware"
TESTS_FW = ROOT / "tests" / "firmware"
MICROPYTHON = Path(sys.executable).parent / "micropython"

# Runs under the unix port. STEP_MODULE: the module whose `step` is compared with the plain one.
COMPARE = r'''
import array, sys, test_alloc as T
from ropenode import kernel, node as N
from ropenode.config import parse
import STEP_MODULE as V
assert N.K.__name__.endswith("kernel_viper"), N.K.__name__  # the Node picks viper here
COUNT = SAMPLES


def walk(ropes, chans, count, seed):
    """Random walks over the whole 4..20 mA span: slow and fast, reversing, with rests."""
    rnd = T.Rand(seed)
    w = 2 * ropes + 4
    out = array.array("H", bytes(2 * w * count))
    p = [0] * ropes
    x = [0] * ropes
    for i in range(ropes):
        p[i] = chans[i][0] + 1000
        x[i] = chans[i][3] + 1000
    speed = 0
    for k in range(count):
        fast = (k // 300) % 3  # 0 rest, 1 slow, 2 fast
        for i in range(ropes):
            c4, flo, fhi, dlo, dflo, dfhi = chans[i]
            c20 = c4 + (fhi - c4) * 16 // 17
            step = (0, 40, 2000)[fast]
            p[i] = min(max(p[i] + rnd.below(2 * step + 1) - step, c4), c20)
            x[i] = min(max(x[i] + rnd.below(2 * step + 1) - step, dlo), dfhi)
            out[k * w + i] = p[i]
            out[k * w + ropes + i] = x[i]
        speed = (speed + rnd.below(41) - 20) & 0xFFFF
        out[k * w + 2 * ropes] = 30000 + rnd.below(20000)
        out[k * w + 2 * ropes + 1] = 9600 + rnd.below(38400)
        out[k * w + 2 * ropes + 2] = speed
        out[k * w + 2 * ropes + 3] = 1 if k % 997 < 2 else 0
    return out


def compare(doc, recs, ropes, tag):
    cfg = parse(doc or T.load_node_json())
    a = N.Node(cfg, step=V.step)
    b = N.Node(cfg, step=kernel.step)
    w = 2 * ropes + 4
    rec = array.array("H", bytes(2 * w))
    ba = bytearray(T.MAX_WIRE_LEN)
    bb = bytearray(T.MAX_WIRE_LEN)
    count = len(recs) // w
    frames = 0
    neg = 0
    for k in range(count):
        rec[:] = recs[k * w:(k + 1) * w]
        ra = a.sample(rec)
        rb = b.sample(rec)
        if ra != rb or bytes(a.S) != bytes(b.S):
            diff = [j for j in range(len(a.S)) if a.S[j] != b.S[j]]
            print("MISMATCH", tag, "record", k, list(rec), "S indices", diff,
                  [a.S[j] for j in diff], [b.S[j] for j in diff])
            return 0
        if ra:
            for i in range(ropes):
                if a.S[N.K.OUT_ROPES + 4 * i + 1] < 0 and a.S[N.K.OUT_ROPES + 4 * i + 1] != -32768:
                    neg += 1  # a negative window minimum: floor division of negative sums compared too
            na = a.frame_into(ba)
            nb = b.frame_into(bb)
            assert ba[:na] == bb[:nb], (tag, k)
            frames += 1
    print("EQUAL", tag, count, frames, "negative-min", neg)
    return count


total = 0
for doc, ropes_seed in ((None, 1), (T.variant_doc(temp_fitted=True), 5),
                        (T.variant_doc(ropes=1, temp_fitted=True), 6), (T.variant_doc(ropes=3, stroke=True), 3),
                        (T.variant_doc(compliance=True, stroke=True), 8)):
    node, ropes, chans = T.build_node(doc)
    w = 2 * ropes + 4
    recs = T.hot_path_records(ropes, chans, 2400, ropes_seed)
    if doc is not None:
        for k in range(2400):
            recs[k * w + 2 * ropes + 1] = (k * 53) & 0xFFFF if k % 3 else 9600 + (k * 37) % 38400
    total += compare(doc, recs, ropes, "faults%d" % ropes_seed)
    total += compare(doc, walk(ropes, chans, COUNT, ropes_seed + 100), ropes, "walk%d" % ropes_seed)
print("TOTAL", total)
'''


def run_compare(tmp_path: Path, step_module: str, samples: int, extra: dict[str, str] | None = None):
    d = tmp_path / "extra"
    d.mkdir(exist_ok=True)
    for name, text in (extra or {}).items():
        (d / name).write_text(text)
    script = tmp_path / "compare.py"
    script.write_text(COMPARE.replace("STEP_MODULE", step_module).replace("SAMPLES", str(samples)))
    env = dict(os.environ, MICROPYPATH=os.pathsep.join([str(FIRMWARE), str(TESTS_FW), str(d)]))
    return subprocess.run([str(MICROPYTHON), "-X", "heapsize=8M", str(script)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)


def test_viper_module_is_generated_from_the_plain_kernel():
    want = gen.generate(gen.KERNEL.read_text())
    assert gen.VIPER.read_text() == want, "run: .venv/bin/python tools/gen_kernel_viper.py"


class _Unextend(ast.NodeTransformer):
    """((X ^ s31) - s31) -> X: the identity on int32 values."""

    def visit_BinOp(self, node):
        self.generic_visit(node)
        if (isinstance(node.op, ast.Sub) and isinstance(node.right, ast.Name) and node.right.id == gen.S31
                and isinstance(node.left, ast.BinOp) and isinstance(node.left.op, ast.BitXor)
                and isinstance(node.left.right, ast.Name) and node.left.right.id == gen.S31):
            return node.left.left
        return node


def _step(src: str) -> ast.FunctionDef:
    return next(n for n in ast.parse(src).body if isinstance(n, ast.FunctionDef) and n.name == gen.FUNC)


def test_viper_step_is_the_plain_step_plus_identities():
    """So test_int32_ast_cpython's range proof of the plain step bounds the viper step's arithmetic."""
    v = _step(gen.VIPER.read_text())
    assert [ast.unparse(d) for d in v.decorator_list] == ["micropython.viper"]
    assert [ast.unparse(s) for s in v.body[1:3]] == ["s31 = 1 << 29", "s31 <<= 2"]
    v.decorator_list = []
    v.returns = None
    for a in v.args.args:
        a.annotation = None
    v.body = v.body[:1] + v.body[3:]
    v = _Unextend().visit(v)
    assert ast.dump(v) == ast.dump(_step(gen.KERNEL.read_text()))


def test_generator_refuses_code_outside_the_viper_subset():
    base = "def step(S, P, rec, n):\n    x = 1\n    {}\n    return 0\n"
    for line, why in (("x = not x", "not"), ("x = 1 if x else 2", "conditional"), ("x = abs(x)", "call"),
                      ("x = S.x", "Attribute"), ("S[0] *= 3", "not exact"),
                      ("x = 1 / 2", "Div"), ("x = 1073741824", "literal")):
        with pytest.raises(gen.ViperError, match=why):
            gen.generate(base.format(line))


def test_viper_kernel_equals_plain_kernel_bit_for_bit(tmp_path):
    r = run_compare(tmp_path, "ropenode.kernel_viper", 20000)
    out = r.stdout + r.stderr
    assert r.returncode == 0 and "MISMATCH" not in out, out
    assert out.count("EQUAL") == 10 and "TOTAL %d" % (5 * (2400 + 20000)) in out, out
    assert any(int(line.split()[-1]) > 0 for line in out.splitlines() if line.startswith("EQUAL")), out


def test_comparison_catches_a_kernel_without_sign_extension(tmp_path):
    """The check can fail: viper reads int32 zero-extended on x86-64, so negative state goes wrong."""
    bad = gen.generate(gen.KERNEL.read_text(), sign_extend=False)
    r = run_compare(tmp_path, "kernel_noext", 400, {"kernel_noext.py": bad})
    assert r.returncode == 0, r.stdout + r.stderr
    assert "MISMATCH" in r.stdout, r.stdout


# --- the source and its helpers ----------------------------------------------------------------

def test_plain_kernel_is_generated_from_the_source():
    """kernel.py is the source with its helpers expanded, calling none of them (only range), and
    expands to itself; the viper module is the same made from either."""
    src = gen.SOURCE.read_text()
    assert gen.KERNEL.read_text() == gen.expand(src), "run: .venv/bin/python tools/gen_kernel_viper.py"
    assert gen.expand(gen.KERNEL.read_text()) == gen.KERNEL.read_text()
    assert gen.generate(src) == gen.VIPER.read_text()
    calls = {n.func.id for n in ast.walk(_step(gen.KERNEL.read_text())) if isinstance(n, ast.Call)}
    assert calls == {"range"}, calls
    helpers = {n.func.id for n in ast.walk(_step(src)) if isinstance(n, ast.Call)} - {"range"}
    assert helpers == {"_q14mul", "_clamp", "_divround"}, helpers


_Q14 = r"\((\w+) >> 14\) \* (\w+) \+ \(\(\1 & 16383\) \* \2 \+ 8192 >> 14\)"


def _q14_products(fn: ast.FunctionDef) -> int:
    """The rounded Q14 products in fn, those spliced into a sum (`X + (e >> 14) * a + ...`,
    which is (X + (e >> 14) * a) + ...) among them."""
    n = 0
    for node in ast.walk(fn):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
            text = ast.unparse(node)
            if re.fullmatch(_Q14, text):
                n += 1
            elif isinstance(node.left, ast.BinOp) and isinstance(node.left.op, ast.Add) \
                    and re.fullmatch(r".* \+ " + _Q14, text) \
                    and re.fullmatch(_Q14, ast.unparse(ast.BinOp(node.left.right, ast.Add(), node.right))):
                n += 1
    return n


def _is_clamp(node: ast.AST) -> bool:
    """`if x > hi: x = hi` / `elif x < lo: x = lo`: what `x = _clamp(x, lo, hi)` expands to."""
    if not (isinstance(node, ast.If) and len(node.body) == 1 and len(node.orelse) == 1
            and isinstance(node.orelse[0], ast.If) and not node.orelse[0].orelse and len(node.orelse[0].body) == 1):
        return False
    inner = node.orelse[0]
    names = []
    for test, body, op in ((node.test, node.body[0], ast.Gt), (inner.test, inner.body[0], ast.Lt)):
        if not (isinstance(test, ast.Compare) and isinstance(test.left, ast.Name) and len(test.ops) == 1
                and isinstance(test.ops[0], op) and isinstance(body, ast.Assign) and len(body.targets) == 1
                and isinstance(body.targets[0], ast.Name) and body.targets[0].id == test.left.id
                and ast.dump(body.value) == ast.dump(test.comparators[0])):
            return False
        names.append(test.left.id)
    return names[0] == names[1]


def test_the_source_writes_each_helper_idiom_once():
    """The source's step writes neither the rounded Q14 product nor the clamp out, nor a split
    division's scratch names; the plain kernel's step has them all (10 products, 19 clamps)."""
    src, plain = _step(gen.SOURCE.read_text()), _step(gen.KERNEL.read_text())
    assert _q14_products(src) == 0 and not [n for n in ast.walk(src) if _is_clamp(n)]
    assert not {"q1", "q2", "q3", "r2", "r3"} & {n.id for n in ast.walk(src) if isinstance(n, ast.Name)}
    assert _q14_products(plain) == 10
    assert len([n for n in ast.walk(plain) if _is_clamp(n)]) == 19
    assert {"q1", "q2", "q3", "r2", "r3"} <= {n.id for n in ast.walk(plain) if isinstance(n, ast.Name)}


def _walk_records(T, ropes, chans, count, seed):
    """COMPARE's walk(): random walks over the whole 4..20 mA span, slow and fast, with rests."""
    rnd = T.Rand(seed)
    w = 2 * ropes + 4
    out = array.array("H", bytes(2 * w * count))
    p = [chans[i][0] + 1000 for i in range(ropes)]
    x = [chans[i][3] + 1000 for i in range(ropes)]
    speed = 0
    for k in range(count):
        step = (0, 40, 2000)[(k // 300) % 3]
        for i in range(ropes):
            c4, flo, fhi, dlo, dflo, dfhi = chans[i]
            c20 = c4 + (fhi - c4) * 16 // 17
            p[i] = min(max(p[i] + rnd.below(2 * step + 1) - step, c4), c20)
            x[i] = min(max(x[i] + rnd.below(2 * step + 1) - step, dlo), dfhi)
            out[k * w + i] = p[i]
            out[k * w + ropes + i] = x[i]
        speed = (speed + rnd.below(41) - 20) & 0xFFFF
        out[k * w + 2 * ropes] = 30000 + rnd.below(20000)
        out[k * w + 2 * ropes + 1] = 9600 + rnd.below(38400)
        out[k * w + 2 * ropes + 2] = speed
        out[k * w + 2 * ropes + 3] = 1 if k % 997 < 2 else 0
    return out


def test_the_source_with_its_helpers_called_is_the_plain_kernel_bit_for_bit():
    """Under CPython the source's step, calling its helpers, and kernel.py's expanded step give
    the same state array after every sample: test_alloc's fault streams and random walks with
    the shipped config and its variants, and a balancing stroke (its start and end); every
    helper call site of the source is reached."""
    sys.path.insert(0, str(TESTS_FW))
    try:
        import test_alloc as T
        from test_compensation_cpython import _stroke_doc, _stroke_wind
    finally:
        sys.path.remove(str(TESTS_FW))
    from ropemon.firmware import node_module
    kernel, parse, Node = node_module("kernel"), node_module("config").parse, node_module("node").Node
    spec = importlib.util.spec_from_file_location("kernel_src_called", gen.SOURCE)
    src = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(src)
    sites = {n.lineno for n in ast.walk(_step(gen.SOURCE.read_text())) if isinstance(n, ast.Call)
             and n.func.id != "range"}
    reached: Counter = Counter()

    def counted(f):
        def call(*args):
            reached[sys._getframe(1).f_lineno] += 1
            return f(*args)
        return call

    for name in ("_q14mul", "_clamp", "_divround"):
        setattr(src, name, counted(getattr(src, name)))

    def compare(doc, rows):
        cfg = parse(doc)
        a, b = Node(cfg, step=src.step), Node(cfg, step=kernel.step)
        rec = array.array("H", bytes(2 * (2 * cfg.ropes + 4)))
        for k, row in enumerate(rows):
            rec[:] = row
            assert a.sample(rec) == b.sample(rec) and bytes(a.S) == bytes(b.S), (k, list(rec))
        return len(rows)

    total = 0
    for doc, seed in ((None, 1), (T.variant_doc(temp_fitted=True, stroke=True), 5),
                      (T.variant_doc(ropes=1, temp_fitted=True), 6), (T.variant_doc(compliance=True), 8),
                      (T.variant_doc(compliance=True, noise_ref_q6=1 << 18, slide_span_q8um=1, stroke=True), 9)):
        doc = doc or T.load_node_json()
        _node, ropes, chans = T.build_node(doc)
        w = 2 * ropes + 4
        recs = T.hot_path_records(ropes, chans, 1000, seed) + _walk_records(T, ropes, chans, 2000, seed + 100)
        total += compare(doc, [recs[k * w:(k + 1) * w] for k in range(len(recs) // w)])
    doc = _stroke_doc(3e-10)
    wind, _x, _p = _stroke_wind(doc["physical"], 3e-10, 33)
    total += compare(doc, [array.array("H", row) for row in wind.tolist()])
    assert total == 5 * 3000 + len(wind)
    assert len(sites) == 31 and sites <= set(reached), sorted(sites - set(reached))


_HELPERS_SRC = '''\
def _mul(x, a):
    """x a / 4, roughly."""
    return (x >> 2) * a + (x & 3)


def _clamp(x, lo, hi):
    if x > hi:
        x = hi
    elif x < lo:
        x = lo
    return x


def _div(a, d):
    q = a // d
    r1 = a - q * d
    q = q + (r1 + (d >> 1)) // d
    return q


def step(S, P, rec, n):
    x = S[0]
    BODY
    return 0
'''


def test_helper_expansion_keeps_the_text_and_means_the_calls():
    """The arguments' own texts in the helpers' (parenthesised only where they must be), a call's
    comment on the expansion's first line, a sum spliced; the expansion and the source run
    alike, and the viper module is the same made from either."""
    body = ("x = _clamp(x, -P[1], P[1])  # held\n"
            "    S[1] = S[2] + _mul(x, 3)\n"
            "    S[2] = _mul(x | 1, 2) * 4\n"
            "    S[3] -= _mul(x, P[2])\n"
            "    q = _div(x, 7)\n"
            "    S[4] = q")
    src = _HELPERS_SRC.replace("BODY", body)
    got = gen.expand(src)
    assert got == gen.PLAIN_HEADER + '''\
def step(S, P, rec, n):
    x = S[0]
    if x > P[1]:  # held
        x = P[1]
    elif x < -P[1]:
        x = -P[1]
    S[1] = S[2] + (x >> 2) * 3 + (x & 3)
    S[2] = (((x | 1) >> 2) * 2 + ((x | 1) & 3)) * 4
    S[3] -= (x >> 2) * P[2] + (x & 3)
    q = x // 7
    r1 = x - q * 7
    q = q + (r1 + (7 >> 1)) // 7
    S[4] = q
    return 0
''', got
    assert gen.generate(src) == gen.generate(got)
    for s0 in range(-40, 41):
        for p1, p2 in ((5, 3), (50, -7), (0, 1)):
            res = []
            for text in (src, got):
                ns: dict = {}
                exec(compile(text, "<kernel>", "exec"), ns)
                S, P = [s0, 0, 9, 100, 0], [0, p1, p2]
                ns["step"](S, P, None, 1)
                res.append(S)
            assert res[0] == res[1], (s0, p1, p2, res)


@pytest.mark.parametrize("body, why", [
    ("y = 1 + _clamp(x, 0, 9)", "statement helper"),
    ("y = _clamp(x, 0, 9)", "assigns its x"),
    ("x = _clamp(x, 0, x + 1)", "which the expansion assigns"),
    ("r1 = 2\n    q = _div(x, 3)", r"locals \['r1'\]"),
    ("q = _div(x, q)", "which the expansion assigns"),
    ("x = _mul(abs(x), 2)", "argument holds a Call"),
    ("x = _mul(x)", "2 positional arguments"),
])
def test_generator_refuses_a_helper_call_whose_expansion_could_differ(body, why):
    with pytest.raises(gen.ViperError, match=why):
        gen.expand(_HELPERS_SRC.replace("BODY", body))


@pytest.mark.parametrize("helper, why", [
    ("def _h(a):\n    return abs(a)\n", "Call is not allowed"),
    ("def _h(a):\n    if a > 0:\n        t = 1\n    return a\n", "first assigned inside an `if`"),
    ("def _h(a):\n    t = t + a\n    return t\n", "t read before it is assigned"),
    ("def _h(a):\n    S[0] = a\n    return a\n", "assign to one name only"),
    ("def _h(a, b=1):\n    return a\n", "plain positional parameters"),
    ("def _h(a):\n    return a\n\n\ndef pack(c):\n    return _h(c)\n", "used outside step"),
])
def test_generator_refuses_a_helper_outside_the_expandable_form(helper, why):
    src = helper + "\n\n" + _HELPERS_SRC.replace("BODY", "x = _h(x)")
    with pytest.raises(gen.ViperError, match=why):
        gen.expand(src)
