"""`ropemon study balancing-strokes` on a hand-made wind: shared motion, then a one-piston stroke;
and the command on a simulated one."""
from __future__ import annotations

import numpy as np

from ropemon import cli
from ropemon.lab import evaluate as EV
from ropemon.lab.studies import balancing_strokes as bs


def test_a_stroke_is_counted_and_the_oil_balance_holds():
    hz, k = 10, 0.3e-9
    t = np.arange(0, 20, 1 / hz)
    p = 5e6 - 50e3 * t                        # 50 kPa/s: 4 k dp = 60 um per second
    dmove = np.diff(4 * k * p, prepend=4 * k * p[0])
    share = np.full((len(t), 4), 0.25)
    share[t >= 10] = [1.0, 0.0, 0.0, 0.0]     # rope 1 takes it all for the last 10 s
    x = np.cumsum(dmove[:, None] * share, axis=0)
    r = bs.analyse({"piston_x_m": x, "p_cav_Pa": np.repeat(p[:, None], 4, axis=1)}, hz, k)
    assert r["seconds"] == 19 and r["moving_seconds"] == 19
    assert r["sum_dx_vs_compression_rms_um"] < 1e-6
    assert r["stroke_seconds"] == 9 and r["stroke_seconds_per_rope"] == [9, 0, 0, 0]
    assert r["largest_share_histogram"]["<0.3"] == 9 and r["largest_share_histogram"]["0.95-1.05"] == 9


def test_the_command_on_the_short_wind(tmp_path, capsys):
    run = tmp_path / "short-test"
    EV.simulate("short-test", run / "sim", 1)
    assert cli.main(["study", "balancing-strokes", str(run)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"{run}: 6 s")  # 7 s of truth: six whole 1 s blocks apart
    rms = float(out.split("compression N k dp: ")[1].split(" um rms")[0])
    assert 0 <= rms < 5  # the cavities are joined: the pistons' motion is the oil's compression
    assert "balancing strokes (one piston > half of it): " in out
