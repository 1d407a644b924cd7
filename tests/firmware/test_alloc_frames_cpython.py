"""No per-sample call frame goes to the heap (tools/check_frame_spill.py).

MicroPython gives a bytecode function with more than 11 words of locals and
stack a heap frame on every call (freed on return, invisible to heap_lock).
The static check reads each function's frame size from mpy-cross output; it is
tested here on functions of known size, then applied to the per-sample path.
"""
from __future__ import annotations

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
