"""fit-friction checks its own fit where the bed knows the truth (its force sensor): the node's
float reference run over the bed's record with the fitted seal and with no friction compensation
(raw p x A), each against the bed's force; a fit that reads it worse than raw p x A beyond the
bed's noise is refused with the figures, and nothing is written. The bed is the lab's simulated
one (the example LuGre seal, four pressure levels: each level is also checked against the lines
fitted without it)."""
from __future__ import annotations

import contextlib
import io
import json
import re

import pytest

from ropemon.cli import main as ropemon
from ropemon.commission import calibrate
from ropemon.lab import testbed

PRESSURES = (2.0, 5.0, 8.0, 11.0)


@pytest.fixture(scope="module")
def accepted(tmp_path_factory):
    """The bed's record and `ropemon fit-friction` on it: (csv, friction.json document, stderr)."""
    tmp = tmp_path_factory.mktemp("bed")
    testbed.write_csv(tmp / "bed.csv", testbed.run(testbed.PAPER_SEAL, pressures_MPa=PRESSURES, seed=7))
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = ropemon(["fit-friction", str(tmp / "bed.csv"), "--out", str(tmp / "friction.json")])
    assert rc == 0, err.getvalue()
    return tmp / "bed.csv", json.loads((tmp / "friction.json").read_text()), err.getvalue()


def wrong(doc: dict, factor: float = 2.2) -> dict:
    """The fit with its static and Coulomb friction lines `factor` times too large, its check removed."""
    out = {k: v for k, v in json.loads(json.dumps(doc)).items() if k != "check"}
    for key in ("Fs", "Fc"):
        out[key] = dict(doc[key], slope=doc[key]["slope"] * factor, intercept=doc[key]["intercept"] * factor)
    return out


def rms(line: str) -> tuple[float, float]:
    """(with the fit, raw p x A) RMS in N of a printed line of the check."""
    m = re.search(r"with the fit (\d+) N rms \((\d+) N worst\), raw p x A (\d+) N rms", line)
    assert m, line
    return float(m.group(1)), float(m.group(3))


def test_a_good_bed_fit_is_accepted_with_its_check_recorded(accepted):
    csv, doc, err = accepted
    chk = doc["check"]
    assert chk["verdict"] == "ok" and chk["data"] == "held-out levels"
    # the bed's force noise (30 N + 0.5 %: 50-100 N here) and three times it as the tolerance
    assert 40 < chk["noise_N"] < 100 and chk["tolerance_N"] == pytest.approx(3 * chk["noise_N"])
    n = len(calibrate.read_csv(csv).t)
    for figures in ("held_out", "in_sample"):
        parts = chk[figures]
        assert set(parts) == {"all", "sliding", "rest"}
        assert parts["sliding"]["samples"] + parts["rest"]["samples"] == parts["all"]["samples"] == n
        for part in parts.values():
            # raw p x A errs by the whole friction (4-13 kN), the node with the fit by well under half of it:
            # what is left is mostly its position filters' lag behind each of the bed's reversals
            assert part["fit_rms_N"] < 0.45 * part["raw_rms_N"], (figures, part)
            assert 7000 < part["raw_rms_N"] < 8000
    assert chk["worst"]["harm_N"] < -4000
    rows = [ln for ln in err.splitlines() if ln.startswith("fit-friction: check on the bed's force")]
    assert len(rows) == 6 and "(held out): rest" in rows[2] and "(as written): all" in rows[3]
    assert "error" not in err


def test_a_fit_that_reads_the_bed_worse_than_raw_is_refused_with_the_figures(accepted, tmp_path, capsys,
                                                                             monkeypatch):
    """A fit whose friction lines are 2.2 times the seal's, injected where the command takes the fit:
    the node then errs by more than the friction itself. Its held-out figures come from the per-level
    Stribeck fits (unchanged, better than raw); the lines as written decide."""
    csv, doc, _ = accepted
    monkeypatch.setattr(calibrate, "fit", lambda rec, source="": (wrong(doc), [], []))
    out = tmp_path / "friction.json"
    assert ropemon(["fit-friction", str(csv), "--out", str(out)]) == 1
    cap = capsys.readouterr()
    assert not out.exists() and cap.out == ""
    msg = cap.err[cap.err.index("fit-friction: error:"):]
    assert msg.startswith("fit-friction: error: the fit reads the bed's force worse than raw p x A: sliding")
    assert "(the fit as written, on its whole record)" in msg and "nothing written" in msg
    fit_rms, raw_rms = rms(msg)
    assert fit_rms > raw_rms + 1000 and 7000 < raw_rms < 8000
    assert "beyond the tolerance" in msg and "x the bed's force noise" in msg
    rows = [ln for ln in cap.err.splitlines() if ln.startswith("fit-friction: check on the bed's force")]
    for ln in rows:
        f, r = rms(ln)
        assert (f > r) if "(as written)" in ln else (f < 0.45 * r), ln
    held = {ln.split(": ")[2].split(" (")[0]: rms(ln)[0] for ln in rows if "(held out)" in ln}
    assert held == {p: round(doc["check"]["held_out"][p]["fit_rms_N"]) for p in ("all", "sliding", "rest")}


def fig(fit_rms: float, raw_rms: float) -> dict:
    return {"samples": 100, "fit_rms_N": fit_rms, "fit_max_N": 3 * fit_rms, "raw_rms_N": raw_rms,
            "raw_max_N": 2 * raw_rms}


@pytest.mark.parametrize("rest_fit,verdict", [(5000.0, "ok"), (8100.0, "marginal"), (8300.0, "worse")])
def test_the_verdict_and_its_tolerance(rest_fit, verdict):
    parts = {"all": fig(3000.0, 7500.0), "sliding": fig(3000.0, 7400.0), "rest": fig(rest_fit, 8000.0)}
    chk = calibrate.BedCheck(parts, parts, True, 65.0, 195.0)
    assert chk.verdict == verdict and chk.worst == ("parts", "rest")
    assert chk.as_dict()["worst"] == {"figures": "held_out", "part": "rest", "harm_N": rest_fit - 8000.0}


def test_fewer_levels_than_can_be_left_out_check_the_fit_on_its_own_record():
    data = testbed.run(testbed.PAPER_SEAL, pressures_MPa=(3.0, 6.0, 9.0), presliding=False, hold_s=1.5, seed=3)
    rec = calibrate.Record(data["time_s"], data["pressure_MPa"], data["velocity_m_s"], data["friction_N"])
    doc, _, _ = calibrate.fit(rec)
    chk = calibrate.check_bed(rec, doc)
    assert not chk.held_out and chk.as_dict()["data"] == "the fit's own record"
    assert chk.as_dict()["held_out"] is None and chk.verdict == "ok"
