"""The example site is the reference board as wired: scenarios/paper-site.toml, built into a
node config by `ropemon config`, reads its 4-20 mA loops at the stream words the board HAL
(firmware/ropenode/hal_board.py) produces for 4, 20, 3.6 and 21 mA.

The HAL's figures come from the HAL itself: the shunt (`_SHUNT_OHM`), the ADS1115 gain from
the PGA field of its config word (`_CFG_BASE`, the datasheet's full scales), and the code ->
stream word step by running `Board._read` on a fake I2C bus. Nothing of the board is restated
here.
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


class _OneCodeI2C:
    """Every ADS1115 on the bus returns `code` from its conversion register."""
    code = 0

    def __init__(self, *a, **k):
        pass

    def writeto_mem(self, addr, reg, data):
        pass

    def readfrom_mem_into(self, addr, reg, buf):
        buf[0], buf[1] = (self.code >> 8) & 0xFF, self.code & 0xFF


class _Any:
    IN = PULL_UP = PERIODIC = 0

    def __init__(self, *a, **k):
        pass


@pytest.fixture
def hal_board(monkeypatch):
    install_shim()
    machine = types.ModuleType("machine")
    for name in ("UART", "WDT", "Counter", "Pin", "Timer"):
        setattr(machine, name, _Any)
    machine.I2C = _OneCodeI2C
    monkeypatch.setitem(sys.modules, "machine", machine)
    monkeypatch.delitem(sys.modules, "ropenode.hal_board", raising=False)
    mod = importlib.import_module("ropenode.hal_board")
    monkeypatch.setattr(mod, "time", types.SimpleNamespace(ticks_ms=lambda: 0))
    yield mod
    sys.modules.pop("ropenode.hal_board", None)


def _board_word(mod, ma: float) -> int:
    """The stream word the reference board produces for a loop current of `ma`."""
    volts_per_code = PGA_FULL_SCALE_V[(mod._CFG_BASE >> 9) & 7] / 32768
    board = mod.Board(None, 1, 200)
    board.i2c.code = min(round(ma / 1000 * mod._SHUNT_OHM / volts_per_code), 0x7FFF)
    return board._read(0)


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
