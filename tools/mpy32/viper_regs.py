"""Why viper code from .mpy runs slower than the same code compiled on the device.

    .venv/bin/python tools/mpy32/viper_regs.py [--repeats N]

mpy-cross is built with MICROPY_PERSISTENT_CODE_SAVE, and with it the native emitter
(py/emitnative.c) keeps a pointer to the module's qstr table in REG_LOCAL_3 and so at most
2 locals in registers; an interpreter compiling the source itself keeps 3 there (and writes
qstrs into the code as immediates). Locals are numbered arguments first, then in order of
first assignment. Two viper loops show it: `two` (2 locals: in registers either way) and
`three` (the same kind of loop with 3 locals: the third in the stack frame from .mpy). Each
is timed from source and from .mpy (mpy-cross -march for the build) on the unix port, the
i386 build and the Thumb-2 build (qemu-user: the emulator's times); medians of N processes,
each the median of 9 calls of 300,000 iterations.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import tempfile
from pathlib import Path

from ropemon.firmware import micropython_command
from ropemon.lab.bench.firmware import _tool

ROOT = Path(__file__).resolve().parents[2]
MPY32 = ROOT / ".cache" / "mpy32"
BUILDS = {  # name: (interpreter, mpy-cross -march)
    "unix port, x86-64": (micropython_command(), "x64"),
    "mpy32 i386": (str(MPY32 / "x86" / "micropython"), "x86"),
    "mpy32 Thumb-2 (qemu-arm)": (str(MPY32 / "thumb" / "micropython-qemu"), "armv7m"),
}

MODULE = '''
import micropython


@micropython.viper
def two(n: int) -> int:
    a = 0
    while n > 0:
        a = (a + n) & 0xFFFF
        n -= 1
    return a


@micropython.viper
def three(n: int) -> int:
    a = 0
    b = 1
    while n > 0:
        a = (a + b) & 0xFFFF
        b = (b + n) & 0xFFFF
        n -= 1
    return a + b
'''

RUN = '''
import time, vregs
def t(f, n):
    r = []
    for _ in range(9):
        t0 = time.ticks_us()
        f(n)
        r.append(time.ticks_diff(time.ticks_us(), t0))
    r.sort()
    return r[4] * 1000 / n
print(t(vregs.two, 300000), t(vregs.three, 300000))
'''


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5, help="processes per build and loading (median)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="ropemon-viper-regs-") as t:
        tmp = Path(t)
        (tmp / "src").mkdir()
        (tmp / "src" / "vregs.py").write_text(MODULE)
        (tmp / "run").mkdir()
        (tmp / "run" / "run.py").write_text(RUN)  # not beside vregs.py: sys.path[0] is the script's dir
        print("| build | loaded from | `two` ns/iteration (2 locals) | `three` ns/iteration (3 locals) |")
        print("|---|---|---:|---:|")
        for name, (exe, arch) in BUILDS.items():
            (tmp / arch).mkdir()
            subprocess.run([_tool("mpy-cross"), f"-march={arch}", "-o", str(tmp / arch / "vregs.mpy"),
                            str(tmp / "src" / "vregs.py")], check=True)
            res = {"source (.py)": [], ".mpy": []}
            for _ in range(a.repeats):
                for loading, path in (("source (.py)", tmp / "src"), (".mpy", tmp / arch)):
                    r = subprocess.run([exe, str(tmp / "run" / "run.py")], env=dict(os.environ, MICROPYPATH=str(path)),
                                       capture_output=True, text=True, timeout=300, check=True)
                    res[loading].append([float(x) for x in r.stdout.split()])
            for loading, runs in res.items():
                two = statistics.median(x[0] for x in runs)
                three = statistics.median(x[1] for x in runs)
                print(f"| {name} | {loading} | {two:.2f} | {three:.2f} |")


if __name__ == "__main__":
    main()
