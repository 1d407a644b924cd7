"""tools/balancing_strokes.py on a hand-made wind: shared motion, then a one-piston stroke."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("balancing_strokes", ROOT / "tools" / "balancing_strokes.py")
bs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bs)


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
