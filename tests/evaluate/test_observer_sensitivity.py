"""`ropemon study observer-sensitivity` runs a scenario and prints one row per observer setting."""
from __future__ import annotations

import re

from ropemon import cli


def test_sensitivity_table_has_every_setting(tmp_path, capsys):
    assert cli.main(["study", "observer-sensitivity", "short-test", "--quick", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| ") and not line.startswith("| setting")]
    labels = [r.split("|")[1].strip() for r in rows]
    assert labels[0] == "as commissioned"
    assert "no compliance (1 Hz position low-pass)" in labels  # the scenario's k was fitted
    assert sum(lab.startswith("k x ") for lab in labels) == 4
    assert sum(lab.startswith("stroke_sigmas ") for lab in labels) == 2
    assert "balancing strokes not tracked (stroke_sigmas 0)" in labels
    assert sum(lab.startswith("rest_sigmas ") for lab in labels) == 2
    assert "no rest hold (rest_sigmas 0)" in labels
    # the pressure tracker: its bounce 0.3 Hz either side, its damping and process noises
    assert sum(lab.startswith("bounce_hz ") for lab in labels) == 2
    assert sum(lab.startswith("bounce_filter_damping ") for lab in labels) == 2
    assert sum(lab.startswith(("creep_q_Pa2_s3 x ", "bounce_q_Pa2_s3 x ")) for lab in labels) == 4
    # each row: play (um) and four figures, numbers; the plays differ with the multiplier,
    # and with the tracker's bandwidth (more process noise: more of the pressure noise passes)
    plays = {lab: float(r.split("|")[2]) for lab, r in zip(labels, rows)}
    assert plays["friction_play_sigmas 1.2"] < plays["as commissioned"] < plays["friction_play_sigmas 2"]
    assert plays["creep_q_Pa2_s3 x 0.333"] < plays["as commissioned"] < plays["creep_q_Pa2_s3 x 3"]
    for r in rows:  # setting | play | rope RMS | rope peak | pithead empty | pithead arrived
        cells = [c.strip() for c in r.strip("|").split("|")]
        assert len(cells) == 6, r
        play, rms, peak = (float(c) for c in cells[1:4])
        assert play > 0 and 0 < rms <= peak, r
        for c in cells[4:]:  # a figure, or "-" where the scenario has no such rest
            assert c == "-" or re.fullmatch(r"[-+]?[0-9]+\.[0-9]+", c), r
