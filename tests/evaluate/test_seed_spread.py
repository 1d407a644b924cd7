"""`ropemon study seed-spread` runs `ropemon evaluate` per seed and tabulates `lugre-p+loss`."""
from __future__ import annotations

from ropemon import cli
from ropemon.lab.studies import seed_range


def test_seed_range_parses_spans_and_lists():
    assert seed_range("1-3") == [1, 2, 3]
    assert seed_range("2,5-6") == [2, 5, 6]


def test_spread_table_has_a_row_per_scenario_over_the_seeds(tmp_path, capsys):
    assert cli.main(["study", "seed-spread", "short-test", "--seeds", "1-2", "--jobs", "2", "--quick",
                     "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| short-test")]
    assert len(rows) == 1, out
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    rms, peak = float(cells[1]), float(cells[2])
    assert 0 < rms <= peak
    assert cells[4].endswith("of 0")  # short-test ends loaded: no empty-cage pithead rest
    lo, med, hi = (float(v) for v in cells[5].split("/"))  # the arrival rest, over both seeds
    assert lo <= med <= hi
    assert [int(v) for v in cells[7].split("/")] == [0, 0]  # operator alarms: none false, none missed
    assert cells[8] == "2 of 2"  # commissioned on both seeds
    assert (tmp_path / "seed-1").is_dir() and (tmp_path / "seed-2").is_dir()
    assert "- short-test: -, -" in out  # per seed: no empty-cage figure
