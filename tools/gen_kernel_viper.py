"""Generate the node kernel's two builds from tools/kernel_src.py (maintainer script, CPython).

    .venv/bin/python tools/gen_kernel_viper.py           # rewrites kernel.py and kernel_viper.py
    .venv/bin/python tools/gen_kernel_viper.py --check   # exit 1 if either is not up to date

The source, tools/kernel_src.py, names a few fixed-point idioms of `step` once, as
helper functions (the top-level functions `step` calls: `_q14mul`, `_clamp`,
`_divround`). Neither build calls them: the generator expands every call inline,
so each build's `step` is straight-line integer code, one call per sample.

firmware/ropenode/kernel.py (the plain build) is the source's text with each helper
call replaced by the helper's body, its parameters replaced by the call's argument
texts, and the helper definitions left out; comments and layout are kept. A helper is
an expression helper (its body only `return EXPR`: usable in any expression) or a
statement helper (statements, then `return EXPR`: usable only as `NAME = helper(...)`,
the statements in its place, then `NAME = EXPR` unless EXPR is NAME). An expression
helper called as the right operand of `+` is spliced without parentheses
(`X + helper(...)` -> `X + A + B` for a body `A + B`): the sum is the same for ints,
left to right as the code had it before the helper. The expansion is the call's
meaning exactly because the generator refuses anything else (ViperError): helper
bodies of Assign/AugAssign/If on names only, no calls, their own names each assigned
before it is read; a parameter the helper assigns takes the call's target name; the
helper's other locals appear nowhere in `step` (but as that target); the arguments
hold no calls and no name the expansion assigns. The text expansion is checked
against an AST expansion (same tree, or ViperError), and the expanded `step`
against the viper subset.

The viper module is kernel.py with `step` compiled by @micropython.viper:
arguments typed (rec: ptr16, P and S: ptr32, n: int), and every read of P or S
sign-extended, `((X ^ s31) - s31)` with s31 = 2**31, because viper reads a
ptr32 element zero-extended on 64-bit ports (on 32-bit ports the expression is
the identity). Compound assignments to P/S elements stay as they are: they
use only + - | & ^, which are exact modulo 2**32, and the store keeps 32 bits.
tests/firmware/test_kernel_viper_cpython.py checks the checked-in files are this
output, that the source (its helpers called) and kernel.py agree bit for bit under
CPython, and that the two kernels agree bit for bit on the unix port.
"""
from __future__ import annotations

import ast
import copy
import io
import sys
import tokenize
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "tools" / "kernel_src.py"
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
PLAIN_HEADER = ("# GENERATED from tools/kernel_src.py by tools/gen_kernel_viper.py (its helpers expanded "
                "inline): do not edit.\n")


class ViperError(ValueError):
    pass


# --- helper expansion (source -> plain kernel) ------------------------------------------------

@dataclass
class _Helper:
    fn: ast.FunctionDef
    params: list[str]
    stmts: list[ast.stmt]     # the body after the docstring, without the final return
    ret: ast.expr             # the return expression
    assigned: set[str]        # names the body assigns (parameters among them)

    @property
    def name(self) -> str:
        return self.fn.name

    @property
    def local_names(self) -> set[str]:
        return self.assigned - set(self.params)


def _names(node: ast.AST) -> set[str]:
    return {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}


def _helper(fn: ast.FunctionDef) -> _Helper:
    where = f"helper {fn.name} (line {fn.lineno})"
    a = fn.args
    if a.posonlyargs or a.vararg or a.kwonlyargs or a.kwarg or a.defaults or fn.decorator_list:
        raise ViperError(f"{where}: plain positional parameters only, no decorators")
    params = [p.arg for p in a.args]
    body = fn.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
            and isinstance(body[0].value.value, str):
        body = body[1:]
    if not body or not isinstance(body[-1], ast.Return) or body[-1].value is None:
        raise ViperError(f"{where}: must end in `return EXPR`")
    stmts, ret = body[:-1], body[-1].value
    for node in [n for st in stmts for n in ast.walk(st)] + list(ast.walk(ret)):
        if isinstance(node, (ast.Call, ast.Return, ast.Lambda, ast.NamedExpr, ast.FunctionDef, ast.Global,
                             ast.Nonlocal, ast.For, ast.While, ast.With, ast.Try, ast.Delete)):
            raise ViperError(f"{where} line {node.lineno}: {type(node).__name__} is not allowed in a helper")
        if isinstance(node, ast.stmt) and not isinstance(node, (ast.Assign, ast.AugAssign, ast.If, ast.Pass)):
            raise ViperError(f"{where} line {node.lineno}: only assignments and `if` in a helper")
        if isinstance(node, ast.Assign) and not (len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)):
            raise ViperError(f"{where} line {node.lineno}: assign to one name only")
        if isinstance(node, ast.AugAssign) and not isinstance(node.target, ast.Name):
            raise ViperError(f"{where} line {node.lineno}: assign to one name only")
    assigned: set[str] = set()

    def check(block: list[ast.stmt], defined: set[str], top: bool) -> None:
        # each local of the helper assigned (at the top level of its body) before it is read
        for s in block:
            if isinstance(s, ast.Pass):
                continue
            value = s.test if isinstance(s, ast.If) else s.value
            target = None if isinstance(s, (ast.If, ast.Pass)) else (
                s.target if isinstance(s, ast.AugAssign) else s.targets[0])
            reads = _names(value) | ({target.id} if isinstance(s, ast.AugAssign) else set())
            for name in reads:
                if name in assigned_anywhere and name not in defined:
                    raise ViperError(f"{where} line {s.lineno}: {name} read before it is assigned")
            if isinstance(s, ast.If):
                check(s.body, set(defined), False)
                check(s.orelse, set(defined), False)
            elif target is not None:
                if target.id not in defined and not top:
                    raise ViperError(f"{where} line {s.lineno}: local {target.id} first assigned inside an `if`")
                defined.add(target.id)
                assigned.add(target.id)

    assigned_anywhere = {n.id for st in stmts for n in ast.walk(st) if isinstance(n, ast.Name)
                         and isinstance(n.ctx, ast.Store)}
    check(stmts, set(params), True)
    for name in _names(ret):
        if name in assigned_anywhere and name not in assigned | set(params):
            raise ViperError(f"{where}: {name} returned but not assigned")
    if stmts == [] and assigned:
        raise ViperError(f"{where}: internal: an expression helper assigns")
    if not stmts and ret.lineno != ret.end_lineno:
        raise ViperError(f"{where}: an expression helper's return fits one line")
    return _Helper(fn, params, stmts, ret, assigned)


class _Subst(ast.NodeTransformer):
    def __init__(self, args: dict[str, ast.expr]):
        self.args = args

    def visit_Name(self, node):
        if node.id in self.args:
            new = copy.deepcopy(self.args[node.id])
            if isinstance(node.ctx, ast.Store):
                new.ctx = ast.Store()  # an assigned parameter's argument is a Name
            return new
        return node


def _rotate(x: ast.expr, e: ast.expr) -> ast.expr:
    """The tree of `X + E` written without parentheses around E (a sum is parsed left to right)."""
    if isinstance(e, ast.BinOp) and isinstance(e.op, (ast.Add, ast.Sub)):
        return ast.BinOp(_rotate(x, e.left), e.op, e.right)
    return ast.BinOp(x, ast.Add(), e)


_SPLICE_TOPS = (ast.Add, ast.Sub, ast.Mult, ast.FloorDiv, ast.Mod)


@dataclass
class _Site:
    call: ast.Call
    helper: _Helper
    kind: str                      # "stmt": NAME = helper(...); "whole": a statement's whole value;
    #                                "sum": right operand of +; "paren": elsewhere
    stmt: ast.stmt | None = None   # kind "stmt": the statement
    parent: ast.BinOp | None = None  # kind "sum": the sum


def _sites(step: ast.FunctionDef, helpers: dict[str, _Helper]) -> list[_Site]:
    step_names = _names(step)
    parents: dict[int, ast.AST] = {}
    for node in ast.walk(step):
        for child in ast.iter_child_nodes(node):
            parents[id(child)] = node
    sites = []
    for node in ast.walk(step):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in helpers):
            continue
        h = helpers[node.func.id]
        where = f"{FUNC} line {node.lineno}: {h.name}"
        if node.keywords or len(node.args) != len(h.params) or any(isinstance(a, ast.Starred) for a in node.args):
            raise ViperError(f"{where}: {len(h.params)} positional arguments")
        for a in node.args:
            for sub in ast.walk(a):
                if isinstance(sub, (ast.Call, ast.NamedExpr, ast.Lambda, ast.Await, ast.Yield, ast.YieldFrom,
                                    ast.ListComp, ast.SetComp, ast.DictComp, ast.GeneratorExp)):
                    raise ViperError(f"{where}: an argument holds a {type(sub).__name__}")
        parent = parents[id(node)]
        target = None
        if h.stmts:
            if not (isinstance(parent, ast.Assign) and parent.value is node and len(parent.targets) == 1
                    and isinstance(parent.targets[0], ast.Name)):
                raise ViperError(f"{where}: a statement helper is called only as `name = {h.name}(...)`")
            target = parent.targets[0].id
            site = _Site(node, h, "stmt", stmt=parent)
        elif isinstance(parent, (ast.Assign, ast.AugAssign, ast.Return)) and parent.value is node:
            site = _Site(node, h, "whole", stmt=parent)
        elif (isinstance(parent, ast.BinOp) and isinstance(parent.op, ast.Add) and parent.right is node
              and (not isinstance(h.ret, (ast.BinOp, ast.BoolOp, ast.Compare, ast.IfExp))
                   or isinstance(h.ret, ast.BinOp) and isinstance(h.ret.op, _SPLICE_TOPS))):
            site = _Site(node, h, "sum", parent=parent)
        else:
            site = _Site(node, h, "paren")
        # what the expansion assigns: the target and the helper's names
        written = h.local_names | ({target} if target else set())
        for p, a in zip(h.params, node.args):
            if p in h.assigned:
                if not (isinstance(a, ast.Name) and a.id == target):
                    raise ViperError(f"{where}: {h.name} assigns its {p}: pass the target name {target}")
            elif _names(a) & written:
                raise ViperError(f"{where}: argument {ast.unparse(a)} reads {sorted(_names(a) & written)}, "
                                 "which the expansion assigns")
        clash = (h.local_names - {target}) & step_names
        if clash:
            raise ViperError(f"{where}: the helper's locals {sorted(clash)} are names of {FUNC} too")
        sites.append(site)
    return sites


def _expansion(s: _Site) -> tuple[list[ast.stmt], ast.expr]:
    """The tree of a site's expansion: the helper's statements and return expression, its
    parameters replaced by the call's arguments (a statement site: with `NAME = EXPR` added
    unless EXPR is NAME, and its expression is that NAME)."""
    h = s.helper
    sub = _Subst(dict(zip(h.params, s.call.args)))
    stmts = [sub.visit(copy.deepcopy(st)) for st in h.stmts]
    ret = sub.visit(copy.deepcopy(h.ret))
    if s.kind == "stmt":
        t = s.stmt.targets[0].id
        if not (isinstance(ret, ast.Name) and ret.id == t):
            stmts.append(ast.Assign([ast.Name(t, ast.Store())], ret))
        ret = ast.Name(t, ast.Load())
    return stmts, ret


def _expand_tree(tree: ast.Module, helpers: dict[str, _Helper], sites: list[_Site]) -> ast.Module:
    """tree (changed in place) with every site expanded and the helper definitions left out."""
    by_call = {id(s.call): s for s in sites if s.kind in ("whole", "paren")}
    by_stmt = {id(s.stmt): s for s in sites if s.kind == "stmt"}
    by_sum = {id(s.parent): s for s in sites if s.kind == "sum"}

    class Expand(ast.NodeTransformer):
        def visit_Assign(self, node):
            s = by_stmt.get(id(node))
            return self.generic_visit(node) if s is None else _expansion(s)[0]

        def visit_BinOp(self, node):
            s = by_sum.get(id(node))
            return self.generic_visit(node) if s is None else _rotate(self.visit(node.left), _expansion(s)[1])

        def visit_Call(self, node):
            s = by_call.get(id(node))
            return self.generic_visit(node) if s is None else _expansion(s)[1]

    tree.body = [n for n in tree.body if not (isinstance(n, ast.FunctionDef) and n.name in helpers)]
    return ast.fix_missing_locations(Expand().visit(tree))


def _token_subst(text: str, repl: dict[str, str]) -> str:
    """text with each NAME token in repl replaced (text: whole lines, or one expression)."""
    lines = text.splitlines(keepends=True)
    edits = []
    try:
        for tok in tokenize.generate_tokens(io.StringIO(text).readline):
            if tok.type == tokenize.NAME and tok.string in repl:
                edits.append((tok.start, tok.end, repl[tok.string]))
    except (tokenize.TokenError, IndentationError) as e:
        raise ViperError(f"cannot tokenize helper text {text!r}: {e}") from e
    for (r0, c0), (r1, c1), new in reversed(edits):
        line = lines[r0 - 1]
        lines[r0 - 1] = line[:c0] + new + line[c1:]
    return "".join(lines)


class _Text:
    """The source's lines, with offsets into the whole text (AST columns are UTF-8 bytes)."""

    def __init__(self, src: str):
        self.src = src
        self.lines = src.splitlines(keepends=True)
        self.starts = [0]
        for ln in self.lines:
            self.starts.append(self.starts[-1] + len(ln))

    def offset(self, line: int, col: int) -> int:
        """The text offset of 1-based `line`, byte column `col`."""
        if line > len(self.lines):
            return len(self.src)
        return self.starts[line - 1] + len(self.lines[line - 1].encode()[:col].decode())

    def segment(self, node: ast.AST) -> str:
        return self.src[self.offset(node.lineno, node.col_offset):self.offset(node.end_lineno, node.end_col_offset)]


_ATOMS = (ast.Name, ast.Constant, ast.Subscript, ast.Attribute)


def _site_text(t: _Text, s: _Site) -> tuple[int, int, str]:
    """(start, end, text) of a site's edit of the source text: the arguments' own texts in the
    helper's text, parenthesised only where the text would not parse to the expansion."""
    h = s.helper
    where = f"{FUNC} line {s.call.lineno}: {h.name}"
    stmts, ret = _expansion(s)
    for wrap in (False, True):
        args = {}
        for p, a in zip(h.params, s.call.args):
            args[p] = t.segment(a)
            if wrap and not isinstance(a, _ATOMS):
                args[p] = f"({args[p]})"
        if s.kind != "stmt":
            text = _token_subst(t.segment(h.ret), args)
            if ast.dump(ast.parse(text, mode="eval").body) == ast.dump(ret):
                if s.kind == "paren":
                    text = f"({text})"
                c = s.call
                return t.offset(c.lineno, c.col_offset), t.offset(c.end_lineno, c.end_col_offset), text
            continue
        st = s.stmt
        first = t.lines[st.lineno - 1]
        tail = t.src[t.offset(st.end_lineno, st.end_col_offset):t.offset(st.end_lineno + 1, 0)].rstrip("\n")
        if first.encode()[:st.col_offset].strip() or tail.strip() and not tail.strip().startswith("#"):
            raise ViperError(f"{where}: the call is alone on its lines (a comment may follow)")
        ind = h.stmts[0].col_offset
        body = []
        for ln in t.lines[h.stmts[0].lineno - 1:h.fn.body[-1].lineno - 1]:
            if ln.strip() and (len(ln) - len(ln.lstrip(" ")) < ind):
                raise ViperError(f"helper {h.name}: its body is not indented evenly")
            body.append(ln[ind:] if ln.strip() else "\n")
        text = _token_subst("".join(body), args)
        if len(stmts) > len(h.stmts):
            text += f"{st.targets[0].id} = {_token_subst(t.segment(h.ret), args)}\n"
        if _dump(ast.parse(text).body) == _dump(stmts):
            out = text.splitlines()
            out[0] += tail
            pad = " " * st.col_offset
            text = "".join(pad + ln + "\n" if ln.strip() else "\n" for ln in out)
            return t.offset(st.lineno, 0), t.offset(st.end_lineno + 1, 0), text
    raise ViperError(f"{where}: its text expansion does not parse to the expansion")


def _dump(nodes) -> str:
    return "\n".join(ast.dump(n) for n in nodes)


def expand(src: str) -> str:
    """The plain kernel's text: `src` with its helpers expanded into `step` and their definitions
    left out, comments kept but for the leading ones, which become PLAIN_HEADER (so the plain
    kernel expands to itself)."""
    tree = ast.parse(src)
    fns = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == FUNC]
    if len(fns) != 1:
        raise ViperError(f"kernel has no single top-level {FUNC}()")
    step = fns[0]
    called = {n.func.id for n in ast.walk(step) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    defs = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name != FUNC}
    helpers = {name: _helper(defs[name]) for name in sorted(called & set(defs))}
    for n in tree.body:
        used = _names(n) & set(helpers)
        if n is not step and not (isinstance(n, ast.FunctionDef) and n.name in helpers) and used:
            raise ViperError(f"line {n.lineno}: helpers {sorted(used)} used outside {FUNC}")
    sites = _sites(step, helpers)
    t = _Text(src)
    edits = [_site_text(t, s) for s in sites]
    for name in helpers:  # the definitions go, with the blank lines after them
        fn = defs[name]
        end = fn.end_lineno
        while end < len(t.lines) and not t.lines[end].strip():
            end += 1
        edits.append((t.offset(fn.lineno, 0), t.offset(end + 1, 0), ""))
    edits.sort(reverse=True)
    text = src
    for k, (a, b, new) in enumerate(edits):
        if k and b > edits[k - 1][0]:
            raise ViperError("internal: overlapping edits")
        text = text[:a] + new + text[b:]
    head = 0  # the source's leading comment (what it is) becomes the generated file's
    while text.startswith("#", head):
        head = text.index("\n", head) + 1
    text = PLAIN_HEADER + text[head:]
    want = _expand_tree(tree, helpers, sites)
    if ast.dump(ast.parse(text)) != ast.dump(want):
        raise ViperError("internal: the text expansion differs from the tree expansion")
    _check_subset(next(n for n in want.body if isinstance(n, ast.FunctionDef) and n.name == FUNC))
    return text


# --- the viper build (plain kernel -> kernel_viper) ----------------------------------------------

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
    """The viper module's text for kernel source `src` (the source or the plain kernel: its helpers
    are expanded first; sign_extend=False: a known-wrong variant)."""
    tree = ast.parse(expand(src))
    fns = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == FUNC]
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
    src = SOURCE.read_text()
    outputs = ((KERNEL, expand(src)), (VIPER, generate(src)))
    if argv == ["--check"]:
        stale = [p for p, want in outputs if p.read_text() != want]
        for p in stale:
            print(f"{p.relative_to(ROOT)} differs from what {SOURCE.relative_to(ROOT)} generates: "
                  "run .venv/bin/python tools/gen_kernel_viper.py", file=sys.stderr)
        if not stale:
            print(" and ".join(str(p.relative_to(ROOT)) for p, _ in outputs) + " are up to date")
        return 1 if stale else 0
    if argv:
        print("usage: gen_kernel_viper.py [--check]", file=sys.stderr)
        return 2
    for p, want in outputs:
        p.write_text(want)
        print(f"wrote {p.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
