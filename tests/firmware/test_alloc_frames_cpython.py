"""No per-sample call frame goes to the heap (tools/check_frame_spill.py).

MicroPython gives a bytecode function with more than 11 words of locals and
stack a heap frame on every call (freed on return, invisible to heap_lock).
The static check reads each function's frame size from mpy-cross output; it is
tested here on functions of known size, then applied to the per-sample path.
"""
from __future__ import annotations

import ast
import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("check_frame_spill", ROOT / "tools" / "check_frame_spill.py")
cfs = importlib.util.module_from_spec(spec)
sys.modules["check_frame_spill"] = cfs  # dataclasses look their module up
spec.loader.exec_module(cfs)

TOY = '''
import micropython


def small(a):
    return a + 1


def thirteen_locals(a):
    b = a + 1; c = b + 1; d = c + 1; e = d + 1; f = e + 1; g = f + 1
    h = g + 1; i = h + 1; j = i + 1; k = j + 1; m = k + 1; n = m + 1
    return a + b + c + d + e + f + g + h + i + j + k + m + n


class C:
    def guarded(self, x):
        try:
            return x
        except ValueError:
            return 0


@micropython.viper
def fast(a: int) -> int:
    b = a + 1; c = b + 1; d = c + 1; e = d + 1; f = e + 1; g = f + 1
    h = g + 1; i = h + 1; j = i + 1; k = j + 1; m = k + 1; n = m + 1
    return a + b + c + d + e + f + g + h + i + j + k + m + n
'''


def test_frame_sizes_of_known_functions(tmp_path):
    src = tmp_path / "toy.py"
    src.write_text(TOY)
    by_name = {f.name: f for f in cfs.frames(src) if f.kind == "bytecode"}
    assert not by_name["small"].spills and by_name["small"].n_state == 3  # a, a, 1 on the stack
    t = by_name["thirteen_locals"]
    assert t.spills and t.n_state >= 13 and t.line == 10
    g = by_name["C.guarded"]
    assert g.n_exc_stack == 1 and g.words == g.n_state + 3
    assert [f.kind for f in cfs.frames(src)].count("viper") == 1  # viper: frame on the C stack


def test_per_sample_functions_keep_their_frames_off_the_heap():
    """Node.sample and the kernel it calls on a port with a native emitter (viper)."""
    node = {f.name: f for f in cfs.frames(ROOT / "firmware" / "ropenode" / "node.py")}
    assert not node["Node.sample"].spills, node["Node.sample"]
    kinds = [f.kind for f in cfs.frames(ROOT / "firmware" / "ropenode" / "kernel_viper.py")]
    assert "viper" in kinds


# --- the board's per-sample path ----------------------------------------------------------
#
# On a board the per-sample work starts in hal_board: the Timer callback that flags a tick,
# and the body of Board.run_forever's loop (step: acquire, record while armed, Node.sample,
# the watchdog feed). The functions it reaches are found from the source's call graph, not
# listed by hand, so a new helper on the path is checked without editing this test.

FIRMWARE = ROOT / "firmware" / "ropenode"
# The modules of the per-sample path. The kernel that Node.sample calls (self.step) is
# kernel_viper's viper `step` on the boards (checked above); the plain kernel is the
# fallback of ports without a native emitter.
PATH_MODULES = ("hal_board", "frontend", "ads1115", "node", "rsens")
# Reached from the loop, but not once per sample: each with why.
NOT_PER_SAMPLE = {
    "Node.frame_into": "once a frame window (20 samples); allocates anyway, collected right after",
    "Writer.close": "once, when the armed recording ends or the flash fails",
}


def _definitions(fw: Path) -> dict:
    """(module, qualified name) -> (class name or None, FunctionDef) of every def in PATH_MODULES."""
    defs = {}
    for mod in PATH_MODULES:
        tree = ast.parse((fw / f"{mod}.py").read_text())
        for node in tree.body:
            if isinstance(node, ast.FunctionDef):
                defs[mod, node.name] = (None, node)
            elif isinstance(node, ast.ClassDef):
                for m in node.body:
                    if isinstance(m, ast.FunctionDef):
                        defs[mod, f"{node.name}.{m.name}"] = (node.name, m)
    return defs


def _imported_modules(fw: Path) -> set[str]:
    """Names bound to modules by `import x` in PATH_MODULES (time, gc, machine, ...)."""
    names = set()
    for mod in PATH_MODULES:
        for node in ast.walk(ast.parse((fw / f"{mod}.py").read_text())):
            if isinstance(node, ast.Import):
                names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return names


def _callees(body, mod: str, cls: str | None, defs: dict, modules: set[str]) -> set[tuple[str, str]]:
    """The defs that calls in `body` (AST nodes) may reach. `self.m()` in class C is C.m when C
    has it; any other `x.m()` or `f()` is every def named m (f) in PATH_MODULES: an
    over-approximation, never a miss. Calls on imported modules (time.ticks_us) and builtins
    resolve to nothing."""
    out = set()
    for root in body:
        for node in ast.walk(root):
            if not isinstance(node, ast.Call):
                continue
            f = node.func
            if isinstance(f, ast.Name):
                out.update(k for k in defs if k[1] == f.id)
            elif isinstance(f, ast.Attribute):
                if isinstance(f.value, ast.Name) and f.value.id in modules:
                    continue
                if isinstance(f.value, ast.Name) and f.value.id == "self" and (mod, f"{cls}.{f.attr}") in defs:
                    out.add((mod, f"{cls}.{f.attr}"))
                else:
                    out.update(k for k in defs if k[1].endswith("." + f.attr))
    return out


def per_sample_functions(fw: Path = FIRMWARE) -> set[tuple[str, str]]:
    """(module, qualified name) of every def reachable, per sample, from the board's Timer
    callback and its loop body."""
    defs = _definitions(fw)
    modules = _imported_modules(fw)
    run = defs["hal_board", "Board.run_forever"][1]
    loops = [n for n in ast.walk(run) if isinstance(n, ast.While)]
    assert len(loops) == 1, "Board.run_forever: expected one sample loop"
    callbacks = [kw.value.attr for n in ast.walk(run) if isinstance(n, ast.Call)
                 for kw in n.keywords if kw.arg == "callback"]
    assert callbacks, "Board.run_forever: no Timer callback"
    todo = _callees(loops[0].body, "hal_board", "Board", defs, modules)
    todo |= {("hal_board", f"Board.{c}") for c in callbacks}
    seen = set()
    while todo:
        k = todo.pop()
        if k in seen or k[1] in NOT_PER_SAMPLE:
            continue
        seen.add(k)
        cls, fn = defs[k]
        todo |= _callees(fn.body, k[0], cls, defs, modules)
    return seen


def spilling(fw: Path = FIRMWARE) -> list:
    """The frames of per-sample functions that go to the heap (with any comprehension in them)."""
    path = per_sample_functions(fw)
    bad = []
    for mod in PATH_MODULES:
        bad += [f for f in cfs.frames(fw / f"{mod}.py") if (mod, f.name) in path and f.spills]
    return bad


def test_the_per_sample_call_graph_reaches_the_front_end_and_the_driver():
    names = {q for _, q in per_sample_functions()}
    assert {"Board._on_timer", "Board.step", "Board._feed_if_healthy", "Board.acquire", "Board._record",
            "FrontEnd.acquire", "FrontEnd._convert", "ADS1115.start", "ADS1115.wait_ready",
            "ADS1115.ready_os", "ADS1115.read_code", "ADS1115._read", "ADS1115._write",
            "Writer.add", "Node.sample"} <= names, sorted(names)
    assert not names & set(NOT_PER_SAMPLE)
    assert "Board.run_forever" not in names and "Board.__init__" not in names  # once per boot


def test_no_function_on_the_boards_per_sample_path_takes_a_heap_frame():
    """Board's tick, the front end, the ADS1115 driver, the recording and Node.sample: every
    bytecode frame within 11 words, so a sample passes nothing through the GC."""
    bad = spilling()
    assert not bad, "\n".join(f"{f.file}:{f.line} {f.name}: {f.words} words" for f in bad)
