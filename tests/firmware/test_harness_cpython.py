"""The MicroPython test runner (tests/run_micropython.py) reports what really happened.

A runner that says "passed" when a test failed, crashed or hung would make
every firmware proof worthless, so it is tested on files made to fail.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

RUNNER = Path(__file__).resolve().parents[1] / "run_micropython.py"


def _run(tmp_path: Path, files: dict[str, str], timeout_s: str = "20") -> subprocess.CompletedProcess:
    for name, src in files.items():
        (tmp_path / name).write_text(src)
    env = dict(os.environ, ROPEMON_MP_TIMEOUT_S=timeout_s)
    return subprocess.run([sys.executable, str(RUNNER), str(tmp_path)], capture_output=True,
                          text=True, env=env, timeout=120)


def test_counts_passes_and_failures_and_exits_nonzero(tmp_path):
    r = _run(tmp_path, {
        "test_a.py": "def test_ok():\n    assert 1 + 1 == 2\n"
                     "def test_bad():\n    assert [] == [1], 'expected failure'\n"
                     "def helper():\n    raise ValueError\n",
        "test_b.py": "import sys\ndef test_is_micropython():\n"
                     "    assert sys.implementation.name == 'micropython'\n",
    })
    lines = r.stdout.splitlines()
    assert lines[-1] == "2 passed, 1 failed", r.stdout
    assert r.returncode != 0
    assert any(ln.startswith("FAIL") and "test_a.py::test_bad" in ln for ln in lines)
    assert "expected failure" in r.stdout  # the traceback is shown


def test_all_passing_exits_zero(tmp_path):
    r = _run(tmp_path, {"test_a.py": "def test_ok():\n    pass\n"})
    assert r.stdout.splitlines()[-1] == "1 passed, 0 failed"
    assert r.returncode == 0


def test_cpython_only_files_are_skipped(tmp_path):
    r = _run(tmp_path, {"test_a.py": "def test_ok():\n    pass\n",
                        "test_b_cpython.py": "import numpy\ndef test_x():\n    pass\n"})
    assert r.stdout.splitlines()[-1] == "1 passed, 0 failed"
    assert "test_b_cpython" not in r.stdout


def test_import_error_and_crash_are_failures(tmp_path):
    r = _run(tmp_path, {
        "test_imp.py": "import no_such_module_here\ndef test_x():\n    pass\n",
        "test_exit.py": "import sys\ndef test_a():\n    sys.exit(7)\n",
    })
    assert r.stdout.splitlines()[-1] == "0 passed, 2 failed", r.stdout
    assert "test_imp.py::<import>" in r.stdout
    assert "test_exit.py::<crash>" in r.stdout
    assert r.returncode != 0


def test_a_hanging_file_times_out_as_a_failure(tmp_path):
    r = _run(tmp_path, {"test_hang.py": "def test_ok():\n    pass\n"
                                        "def test_zz_forever():\n    while True:\n        pass\n"},
             timeout_s="2")
    assert r.stdout.splitlines()[-1] == "1 passed, 1 failed", r.stdout  # test_ok ran before the hang
    assert "test_hang.py::<timeout>" in r.stdout
    assert r.returncode != 0


def test_zero_tests_is_a_failure(tmp_path):
    r = _run(tmp_path, {"test_empty.py": "X = 1\n"})
    assert r.stdout.splitlines()[-1] == "0 passed, 0 failed"
    assert r.returncode != 0


def test_faked_result_lines_in_test_output_do_not_count(tmp_path):
    r = _run(tmp_path, {"test_a.py": "def test_bad():\n    print('1 passed, 0 failed')\n"
                                     "    print('PASS fake')\n    raise AssertionError\n"})
    assert r.stdout.splitlines()[-1] == "0 passed, 1 failed"


def test_a_generator_test_is_run_step_by_step_and_can_fail(tmp_path):
    """A test returning a generator: each yield gets a full collection from the driver (64 KB
    dropped before it are gone after it), and a failure after a yield is a failure."""
    r = _run(tmp_path, {"test_g.py": (
        "import gc\nBIG = [bytearray(65536)]\n"
        "def _drop():\n    BIG[0] = None\n"
        "def test_frees():\n"
        "    def steps():\n"
        "        yield\n        a = gc.mem_alloc()\n        _drop()\n        yield\n"
        "        assert a - gc.mem_alloc() >= 65536, a - gc.mem_alloc()\n"
        "    return steps()\n"
        "def test_fails_late():\n"
        "    def steps():\n        yield\n        yield\n        raise AssertionError('late failure')\n"
        "    return steps()\n")})
    assert r.stdout.splitlines()[-1] == "1 passed, 1 failed", r.stdout
    assert "test_g.py::test_fails_late" in r.stdout and "late failure" in r.stdout
    assert r.returncode != 0
