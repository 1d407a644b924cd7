"""Run the firmware tests under the real MicroPython unix port (`make test`, after pytest).

Usage: .venv/bin/python tests/run_micropython.py [TEST_FILE_OR_DIR ...]
(default: tests/firmware).

Convention: every tests/firmware/test_*.py runs here unless its name ends in
`_cpython.py` (those need CPython: numpy, subprocesses, the host package).
A test is a module-level function `test_*()` taking no arguments that passes
by returning and fails by raising. A test may instead return a generator: each
`yield` in it asks for a full garbage collection from the driver's own level
(no frame of the test on the stack) before the test goes on, which is how a
test measures the heap a release frees (test_boot_heap.py). Here and on the
32-bit builds the driver collects (twice) between steps; on the WebAssembly
port, where gc.collect() only marks a collection that runs when control returns
to JavaScript, tests/wasm/run_wasm.mjs calls STEP_DRIVER's `_step` once per
step and gc.collect in between, each a top-level call. Each file runs in its own `micropython`
subprocess, with MICROPYPATH=firmware:<the test file's directory>, under a
timeout. The last line printed is exactly `N passed, M failed`; the exit code
is non-zero when any test failed, a file could not be imported or timed out,
or no test ran at all.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from ropemon.firmware import micropython_command

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / "firmware"
DEFAULT_DIR = ROOT / "tests" / "firmware"
TIMEOUT_S = float(os.environ.get("ROPEMON_MP_TIMEOUT_S", "300"))

# Lines the driver prints start with this tag so test output cannot fake a result.
TAG = "@@ropemon-test@@"

# Runs inside micropython: import one test module and call each test_* function, one step at a
# time: `_step()` runs a test, or a generator test up to its next yield, and returns 0 when
# all is done, 1 to be called again, 2 to be called again after a full collection.
STEP_DRIVER = """
import sys, time, gc
TAG = %r
try:
    mod = __import__(%r)
except BaseException as e:
    print(TAG, "IMPORT-FAIL")
    sys.print_exception(e)
    sys.exit(3)
_names = [n for n in dir(mod) if n.startswith("test_") and callable(getattr(mod, n))]
_names.sort()
_cur = None  # [name, generator, t0] of a generator test between two of its steps


def _end(n, t0, e):
    if e is None:
        print(TAG, "PASS", n, time.ticks_diff(time.ticks_ms(), t0))
    else:
        print(TAG, "FAIL", n, time.ticks_diff(time.ticks_ms(), t0))
        sys.print_exception(e)


def _step():
    global _cur
    if _cur is None:
        if not _names:
            print(TAG, "DONE")
            return 0
        n = _names.pop(0)
        t0 = time.ticks_ms()
        try:
            g = getattr(mod, n)()
        except Exception as e:
            _end(n, t0, e)
            return 1
        if g is None:
            _end(n, t0, None)
            return 1
        _cur = [n, g, t0]
        return 2
    n, g, t0 = _cur
    try:
        next(g)
    except StopIteration:
        _cur = None
        _end(n, t0, None)
        return 1
    except Exception as e:
        _cur = None
        _end(n, t0, e)
        return 1
    return 2
"""

# The whole run in one script: the unix port, the 32-bit builds (and wasm scripts that need no
# collection between steps). The collections run here, at the script's top level.
DRIVER = STEP_DRIVER + """
while True:
    _r = _step()
    if not _r:
        break
    if _r == 2:
        gc.collect()
        gc.collect()
"""


def discover(args: list[str]) -> list[Path]:
    """Test files named by args (files or directories), MicroPython-compatible ones only."""
    roots = [Path(a).resolve() for a in args] or [DEFAULT_DIR]
    files: list[Path] = []
    for r in roots:
        if r.is_dir():
            files.extend(sorted(r.glob("test_*.py")))
        elif r.is_file():
            files.append(r)
        else:
            raise SystemExit(f"no such test file or directory: {r}")
    return [f for f in files if not f.name.endswith("_cpython.py")]


def run_file(exe: str, path: Path) -> tuple[list[tuple[str, bool, str]], str]:
    """Run one test file; return ([(test, passed, detail)], raw output)."""
    env = dict(os.environ)
    env["MICROPYPATH"] = os.pathsep.join([str(FIRMWARE), str(path.parent)])
    code = DRIVER % (TAG, path.stem)
    try:
        proc = subprocess.run([exe, "-c", code], cwd=ROOT, env=env, capture_output=True,
                              text=True, timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired as e:
        out = (e.stdout or b"").decode() if isinstance(e.stdout, bytes) else (e.stdout or "")
        done = _parse(out)[0]
        return done + [("<timeout>", False, f"no result after {TIMEOUT_S:.0f} s")], out
    out = proc.stdout + proc.stderr
    results, finished, import_failed = _parse(proc.stdout)
    if import_failed:
        results.append(("<import>", False, "module could not be imported"))
    elif not finished:
        results.append(("<crash>", False, f"micropython exited with {proc.returncode} before finishing"))
    return results, out


def _parse(out: str) -> tuple[list[tuple[str, bool, str]], bool, bool]:
    results = []
    finished = import_failed = False
    lines = out.splitlines()
    for i, line in enumerate(lines):
        if not line.startswith(TAG):
            continue
        parts = line.split()
        if parts[1] == "DONE":
            finished = True
        elif parts[1] == "IMPORT-FAIL":
            import_failed = True
        elif parts[1] in ("PASS", "FAIL"):
            detail = f"{parts[3]} ms" if len(parts) > 3 else ""
            if parts[1] == "FAIL":
                tb = []
                for nxt in lines[i + 1:]:
                    if nxt.startswith(TAG):
                        break
                    tb.append(nxt)
                detail += "\n" + "\n".join("      " + t for t in tb)
            results.append((parts[2], parts[1] == "PASS", detail))
    return results, finished, import_failed


def main(argv: list[str]) -> int:
    try:
        exe = micropython_command()
    except FileNotFoundError as e:
        raise SystemExit(f"{e}: run `make .venv/.installed` first") from None
    files = discover(argv)
    passed = failed = 0
    t0 = time.monotonic()
    for path in files:
        rel = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
        results, out = run_file(exe, path)
        for name, ok, detail in results:
            print(f"{'PASS' if ok else 'FAIL'} {rel}::{name} {detail}")
            if ok:
                passed += 1
            else:
                failed += 1
        if any(not ok for _, ok, _ in results) and any(n.startswith("<") for n, _, _ in results):
            print("      output:\n" + "\n".join("      " + ln for ln in out.splitlines()[-30:]))
        sys.stdout.flush()
    print(f"micropython {exe}: {len(files)} files in {time.monotonic() - t0:.1f} s")
    if passed + failed == 0:
        print("no MicroPython tests ran", file=sys.stderr)
    print(f"{passed} passed, {failed} failed")
    return 0 if failed == 0 and passed > 0 else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
