"""The example site is the reference board as wired: scenarios/paper-site.toml, built into a
node config by `ropemon config`, reads its 4-20 mA loops at the stream words the board HAL
(firmware/ropenode/hal_board.py, its front end and ADS1115 driver) produces for 4, 20, 3.6
and 21 mA.

The board's figures come from the firmware itself: the shunt from the reference board's
table (ropenode.boards), the ADS1115 gain from the PGA field of the config word the driver
writes on the bus (the datasheet's full scales), and the code -> stream word step by
running the HAL's acquisition on a fake I2C bus. Nothing of the board is restated here.
"""
from __future__ import annotations

import importlib
import json
import shutil
import sys
import types
from pathlib import Path

import pytest

from ropemon.cli import main as ropemon
from ropemon.firmware import install_shim

SCEN = Path(__file__).resolve().parents[2] / "scenarios"
# ADS1115 datasheet, config register bits 11:9 (PGA): full-scale range in volts
PGA_FULL_SCALE_V = {0: 6.144, 1: 4.096, 2: 2.048, 3: 1.024, 4: 0.512, 5: 0.256, 6: 0.256, 7: 0.256}


class _LoopI2C:
    """Every ADS1115 on the bus sees `volts` on each input: a conversion started by a config
    write (OS = 1) gives the code of that voltage at the PGA the write selects."""
    volts = 0.0

    def __init__(self):
        self.code = 0

    def writeto_mem(self, addr, reg, data):
        word = (data[0] << 8) | data[1]
        if reg == 1 and word & 0x8000:
            lsb = PGA_FULL_SCALE_V[(word >> 9) & 7] / 32768
            self.code = min(round(self.volts / lsb), 0x7FFF)

    def readfrom_mem_into(self, addr, reg, buf):
        v = 0x8000 if reg == 1 else self.code  # config: OS = 1, the conversion is done
        buf[0], buf[1] = (v >> 8) & 0xFF, v & 0xFF


class _Any:
    IN = PULL_UP = PERIODIC = 0

    def __init__(self, *a, **k):
        pass

    def value(self):
        return 1


@pytest.fixture
def hal_board(monkeypatch):
    install_shim()
    machine = types.ModuleType("machine")
    for name in ("UART", "WDT", "Counter", "Pin", "Timer", "I2C"):
        setattr(machine, name, _Any)
    monkeypatch.setitem(sys.modules, "machine", machine)
    monkeypatch.delitem(sys.modules, "ropenode.hal_board", raising=False)
    mod = importlib.import_module("ropenode.hal_board")
    from ropenode import ads1115, frontend
    clock = types.SimpleNamespace(ticks_ms=lambda: 0, ticks_us=lambda: 0, sleep_us=lambda us: None,
                                  ticks_diff=lambda a, b: a - b)
    for m in (mod, ads1115, frontend):
        monkeypatch.setattr(m, "time", clock)
    yield mod
    sys.modules.pop("ropenode.hal_board", None)


def _board_word(mod, ma: float) -> int:
    """The stream word the reference board produces for a loop current of `ma` (rope 1's
    pressure word of one acquired record)."""
    from ropenode import boards

    table = boards.get()  # the board main.py runs (boards.BOARD)
    bus = _LoopI2C()
    bus.volts = ma / 1000 * table["shunt_ohm"]
    board = mod.Board(None, 1, 200, False, table, i2c=bus)
    board.acquire()
    return board.rec[0]


@pytest.fixture
def paper_node_json(tmp_path) -> dict:
    for name in ("paper-site.toml", "paper-friction.json", "paper-compliance.json"):
        shutil.copy(SCEN / name, tmp_path / name)
    out = tmp_path / "node.json"
    assert ropemon(["config", str(tmp_path / "paper-site.toml"), "--out", str(out)]) == 0
    return json.loads(out.read_text())


def test_paper_site_loops_read_as_the_reference_board_scales_them(hal_board, paper_node_json):
    w4, w20 = _board_word(hal_board, 4.0), _board_word(hal_board, 20.0)
    w36, w21 = _board_word(hal_board, 3.6), _board_word(hal_board, 21.0)
    assert 0 < w36 < w4 < w20 < w21 < 65535  # NAMUR faults fall inside the ADC range
    ph, nd = paper_node_json["physical"], paper_node_json["node"]
    for ch in ph["pressure_channels"]:
        assert (ch["counts_4mA"], ch["counts_20mA"]) == (w4, w20)
    for ch in ph["displacement_channels"]:  # 4-20 mA position transmitters on AIN1
        assert (ch["counts_lo"], ch["counts_hi"]) == (w4, w20)
    for ch in nd["pressure"] + nd["displacement"]:  # the node's fault limits: 3.6 and 21 mA
        assert abs(ch["fault_lo_counts"] - w36) <= 1 and abs(ch["fault_hi_counts"] - w21) <= 1
    for ch in nd["pressure"]:
        assert ch["counts_4ma"] == w4
