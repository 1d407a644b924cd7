"""The viper kernel is the plain kernel: generated from it, and bit-exact on the unix port.

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

import ast
import os
import subprocess
import sys
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
