"""The board HAL, which cannot run here, is type-checked against the ESP32 port's stubs.

mypy runs with MicroPython's reduced stdlib as its typeshed
(`micropython-stdlib-stubs`, so `time.ticks_us` exists and CPython-only APIs
do not) and the `micropython-esp32-stubs` modules (machine, esp32, micropython,
...) on MYPYPATH. Both packages are pinned test dependencies; the files they
installed are found from their wheel RECORDs. Every firmware file that imports
`machine` is checked, with untyped function bodies checked too. Errors inside
the stubs themselves are not ours and are ignored; errors in our files fail.
"""
from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "firmware"
MYPY = Path(sys.executable).parent / "mypy"
SITE = Path(sysconfig.get_paths()["purelib"])


def _installed_files(dist_glob: str) -> list[str]:
    records = list(SITE.glob(dist_glob + "*.dist-info/RECORD"))
    assert records, f"{dist_glob} is not installed (pyproject.toml [test] extra)"
    return [line.split(",")[0] for line in records[0].read_text().splitlines()
            if line.split(",")[0].endswith(".pyi") or line.split(",")[0].endswith("VERSIONS")]


@pytest.fixture(scope="module")
def stub_dirs(tmp_path_factory) -> tuple[Path, Path]:
    """(custom typeshed dir, MYPYPATH dir) assembled from the installed stub packages."""
    base = tmp_path_factory.mktemp("mpy_stubs")
    typeshed, typings = base / "typeshed", base / "typings"
    for rel in _installed_files("micropython_stdlib_stubs-"):
        top = rel.split("/")[0]
        dest = (typeshed if top in ("stdlib", "stubs") else typings) / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(SITE / rel, dest)
    for rel in _installed_files("micropython_esp32_stubs-"):
        dest = typings / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(SITE / rel, dest)
    assert (typings / "machine.pyi").exists() and (typeshed / "stdlib" / "VERSIONS").exists()
    return typeshed, typings


def mypy_errors(files: list[Path], stub_dirs: tuple[Path, Path], cache: Path) -> list[str]:
    """mypy error lines that point into `files` (not into the stubs)."""
    typeshed, typings = stub_dirs
    env = {"MYPYPATH": f"{typings}:{FIRMWARE}", "PATH": "/usr/bin:/bin"}
    r = subprocess.run([str(MYPY), "--no-incremental", "--cache-dir", str(cache), "--check-untyped-defs",
                        "--custom-typeshed-dir", str(typeshed), "--python-version", "3.11",
                        "--no-error-summary", "--show-error-codes", *map(str, files)],
                       capture_output=True, text=True, timeout=300, cwd=ROOT, env=env)
    assert r.returncode in (0, 1), r.stdout + r.stderr  # 2 = mypy itself failed
    wanted = {str(f) for f in files} | {str(f.relative_to(ROOT)) for f in files if f.is_relative_to(ROOT)}
    return [ln for ln in r.stdout.splitlines() if ln.split(":")[0] in wanted and ": error:" in ln]


def machine_users() -> list[Path]:
    """Firmware files that import `machine` (only the board HAL should)."""
    out = []
    for p in sorted(FIRMWARE.rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            if any(n == "machine" or n.startswith("machine.") for n in names):
                out.append(p)
                break
    return out


def test_board_hal_is_the_only_machine_user():
    assert (FIRMWARE / "ropenode" / "hal_board.py").exists(), "firmware/ropenode/hal_board.py is missing"
    assert [p.name for p in machine_users()] == ["hal_board.py"]


def test_board_hal_type_checks_against_esp32_stubs(stub_dirs, tmp_path):
    files = machine_users()
    assert files, "no firmware file imports machine"
    errors = mypy_errors(files, stub_dirs, tmp_path / "cache")
    assert not errors, "\n".join(errors)


GOOD_HAL = """
import time
from machine import ADC, Pin, UART, WDT, Timer

def setup():
    adc = ADC(Pin(34))
    adc.atten(ADC.ATTN_11DB)
    uart = UART(2, baudrate=9600, tx=17, rx=16)
    wdt = WDT(timeout=2000)
    tim = Timer(0)
    tim.init(freq=200, mode=Timer.PERIODIC, callback=lambda t: None)
    t0 = time.ticks_us()
    n = adc.read_u16() + time.ticks_diff(time.ticks_us(), t0)
    uart.write(b"x")
    wdt.feed()
    return n
"""

BAD_HAL = """
import time
from machine import ADC, Pin, UART

def setup():
    adc = ADC(Pin(34))
    a = adc.read_u17()
    UART(2).write(b"x", 1)
    p = Pin(5, Pin.OUTT)
    return time.ticks_usec()
"""


def test_checker_accepts_correct_machine_calls(stub_dirs, tmp_path):
    f = tmp_path / "good_hal.py"
    f.write_text(GOOD_HAL)
    assert mypy_errors([f], stub_dirs, tmp_path / "cache") == []


def test_checker_catches_wrong_machine_calls(stub_dirs, tmp_path):
    """The check can fail: four wrong API uses give four errors on their lines."""
    f = tmp_path / "bad_hal.py"
    f.write_text(BAD_HAL)
    errors = mypy_errors([f], stub_dirs, tmp_path / "cache")
    assert sorted(int(e.split(":")[1]) for e in errors) == [7, 8, 9, 10], "\n".join(errors)


# Wrong API uses injected into a copy of the real board HAL, one at a time.
MUTATIONS = (
    (".readfrom_mem_into(", ".readfrom_mem_intox("),
    ("time.sleep_us(", "time.sleep_usec("),
    ("WDT(timeout=", "WDT(timeout_ms="),
    ("Timer.PERIODIC", "Timer.PERIODICAL"),
    ("baudrate=", "baud="),
    ("Pin.PULL_UP", "Pin.PULLUP"),
    ("I2C(bus, scl=", "I2C(bus, scll="),
)


def test_checker_sees_wrong_calls_in_the_real_board_hal(stub_dirs, tmp_path):
    """The real file's machine calls are typed, not Any: each mutation is caught on its line."""
    src = (FIRMWARE / "ropenode" / "hal_board.py").read_text()
    applied = 0
    for k, (old, new) in enumerate(MUTATIONS):
        if old not in src:
            continue
        line = src[:src.index(old)].count("\n") + 1
        f = tmp_path / f"m{k}" / "hal_board.py"
        f.parent.mkdir()
        f.write_text(src.replace(old, new, 1))
        errors = mypy_errors([f], stub_dirs, tmp_path / "cache")
        assert any(int(e.split(":")[1]) == line for e in errors), f"{old} -> {new} not caught:\n" + "\n".join(errors)
        applied += 1
    assert applied >= 3, "hal_board.py changed: update MUTATIONS"
