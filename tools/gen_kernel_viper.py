"""Generate firmware/ropenode/kernel_viper.py from kernel.py (maintainer script, CPython).

    .venv/bin/python tools/gen_kernel_viper.py           # rewrites kernel_viper.py
    .venv/bin/python tools/gen_kernel_viper.py --check   # exit 1 if it is not up to date

The viper module is kernel.py with `step` compiled by @micropython.viper:
arguments typed (rec: ptr16, P and S: ptr32, n: int), and every read of P or S
sign-extended, `((X ^ s31) - s31)` with s31 = 2**31, because viper reads a
ptr32 element zero-extended on 64-bit ports (on 32-bit ports the expression is
the identity). Compound assignments to P/S elements stay as they are: they
use only + - | & ^, which are exact modulo 2**32, and the store keeps 32 bits.
tests/firmware/test_kernel_viper_cpython.py checks the checked-in file is this
output and that the two kernels agree bit for bit on the unix port.
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KERNEL = ROOT / "firmware" / "ropenode" / "kernel.py"
VIPER = ROOT / "firmware" / "ropenode" / "kernel_viper.py"
FUNC = "step"
ARG_TYPES = {"rec": "ptr16", "P": "ptr32", "S": "ptr32", "n": "int"}
INT32_ARRAYS = ("P", "S")
EXACT_AUG_OPS = (ast.Add, ast.Sub, ast.BitOr, ast.BitAnd, ast.BitXor)
S31 = "s31"
HEADER = ('"""GENERATED from kernel.py by tools/gen_kernel_viper.py: do not edit.\n\n'
          "kernel.py with `step` compiled by @micropython.viper (int32 reads sign-extended).\n"
          '"""\n')


class ViperError(ValueError):
    pass


class _SignExtend(ast.NodeTransformer):
    def __init__(self, sign_extend: bool):
        self.sign_extend = sign_extend

    def visit_AugAssign(self, node):
        t = node.target
        if isinstance(t, ast.Subscript) and isinstance(t.value, ast.Name) and t.value.id in INT32_ARRAYS:
            if not isinstance(node.op, EXACT_AUG_OPS):
                raise ViperError(f"line {node.lineno}: {type(node.op).__name__}= on {t.value.id}[...] "
                                 "is not exact on a zero-extended read; write it out")
            t.slice = self.visit(t.slice)
            node.value = self.visit(node.value)
            return node
        return self.generic_visit(node)

    def visit_Subscript(self, node):
        self.generic_visit(node)
        if (self.sign_extend and isinstance(node.ctx, ast.Load) and isinstance(node.value, ast.Name)
                and node.value.id in INT32_ARRAYS):
            x = ast.BinOp(node, ast.BitXor(), ast.Name(S31, ast.Load()))
            return ast.BinOp(x, ast.Sub(), ast.Name(S31, ast.Load()))
        return node


def _check_subset(fn: ast.FunctionDef) -> None:
    """Refuse constructs whose meaning differs under viper (or that viper lacks)."""
    for node in ast.walk(fn):
        bad = None
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.Not, ast.Invert)):
            bad = "`not`/`~` (use == 0 / ^ mask)"
        elif isinstance(node, ast.IfExp):
            bad = "conditional expression"
        elif isinstance(node, ast.Call) and not (isinstance(node.func, ast.Name) and node.func.id == "range"):
            bad = "call"
        elif isinstance(node, (ast.Tuple, ast.List, ast.Dict, ast.Set, ast.Attribute, ast.Lambda)):
            bad = type(node).__name__
        elif isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Div, ast.Pow, ast.MatMult)):
            bad = type(node.op).__name__
        elif isinstance(node, ast.Constant) and not (isinstance(node.value, int) or node is fn.body[0].value):
            bad = f"constant {node.value!r}"
        elif isinstance(node, ast.Constant) and isinstance(node.value, int) and not -(1 << 29) <= node.value < 1 << 29:
            bad = f"literal {node.value} (not a small int on 32-bit ports)"
        if bad:
            raise ViperError(f"{FUNC} line {node.lineno}: {bad} is outside the viper subset")


def generate(src: str, sign_extend: bool = True) -> str:
    """The viper module's text for kernel source `src` (sign_extend=False: a known-wrong variant)."""
    tree = ast.parse(src)
    fns = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == FUNC]
    if len(fns) != 1:
        raise ViperError(f"kernel has no single top-level {FUNC}()")
    fn = fns[0]
    _check_subset(fn)
    for a in fn.args.args:
        if a.arg not in ARG_TYPES:
            raise ViperError(f"{FUNC}: argument {a.arg} has no viper type")
        a.annotation = ast.Name(ARG_TYPES[a.arg], ast.Load())
    fn.returns = ast.Name("int", ast.Load())
    fn.decorator_list = [ast.Attribute(ast.Name("micropython", ast.Load()), "viper", ast.Load())]
    fn = _SignExtend(sign_extend).visit(fn)
    # s31 = 2**31 built by shifting: a literal that big would be an object, not a viper int
    setup = ast.parse(f"{S31} = 1 << 29\n{S31} <<= 2\n").body
    doc = fn.body[:1] if isinstance(fn.body[0], ast.Expr) else []
    fn.body = doc + setup + fn.body[len(doc):]
    body = tree.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        body = body[1:]  # the module docstring is replaced by HEADER
    tree.body = ast.parse("import micropython\n").body + body
    return HEADER + ast.unparse(ast.fix_missing_locations(tree)) + "\n"


def main(argv: list[str]) -> int:
    want = generate(KERNEL.read_text())
    if argv == ["--check"]:
        if VIPER.read_text() == want:
            print(f"{VIPER.relative_to(ROOT)} is up to date")
            return 0
        print(f"{VIPER.relative_to(ROOT)} differs from what kernel.py generates: "
              "run .venv/bin/python tools/gen_kernel_viper.py", file=sys.stderr)
        return 1
    if argv:
        print("usage: gen_kernel_viper.py [--check]", file=sys.stderr)
        return 2
    VIPER.write_text(want)
    print(f"wrote {VIPER.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
