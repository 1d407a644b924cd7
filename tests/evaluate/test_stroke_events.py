"""`ropemon study stroke-events` runs a run directory's stream through the node's kernel and the
float reference (their agreement stroke by stroke: tests/firmware/test_compensation_cpython.py)."""
from __future__ import annotations

from ropemon import cli
from ropemon.lab import evaluate as EV


def test_the_command_on_the_short_wind(tmp_path, capsys):
    work = tmp_path / "short-test"
    EV.build_case("short-test", work, 1, firmware=False, bed=EV.BED_QUICK, diagnostics=False)
    assert cli.main(["study", "stroke-events", str(work), "--until", "5"]) == 0
    out = capsys.readouterr().out.splitlines()
    # 5 s at 200 Hz; the short wind has no balancing stroke, and neither side takes one
    assert out[0] == f"{work}: 1000 samples; strokes started: node 0, reference 0"
    assert not any("<- not the" in line for line in out)
    assert out[-1].startswith("following the node where the two decide apart by rounding: 0 decisions followed, "
                              "0 disputed; frames within ")
