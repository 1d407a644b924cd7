"""Leave-one-family-out (ropemon.lab.generalise): the seeded split, per-phase scoring, do no harm."""
from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

from ropemon.lab import generalise as G
from ropemon.lab import metrics as M
from ropemon.lab import population as P

RATED = 80e3


def test_the_split_is_seeded_and_reproducible():
    for f in G.FAMILIES:
        assert G.family_seeds(f, 6) == G.family_seeds(f, 6)
        assert len(G.family_seeds(f, 6)) == 6
        assert all(G.is_family(s, f) for s in G.family_seeds(f))
    assert [G.held_out_family(s) for s in P.SCORING_SEEDS] == [G.held_out_family(s) for s in P.SCORING_SEEDS]
    # each seed has one present and one held-out family: the held-out ones split the seeds
    dahl, bs = set(G.family_seeds("dahl")), set(G.family_seeds("bliman-sorine"))
    assert not dahl & bs and dahl | bs == set(P.SCORING_SEEDS) and dahl and bs
    present = [set(G.family_seeds(f)) for f in P.LAWS]
    assert set().union(*present) == set(P.SCORING_SEEDS) and sum(map(len, present)) == len(P.SCORING_SEEDS)
    assert G.family_seeds("dahl", 3, P.TUNING_SEEDS) == [s for s in P.TUNING_SEEDS if G.held_out_family(s) == "dahl"][:3]
    with pytest.raises(ValueError):
        G.family_seeds("coulomb-stribeck", 1)


def test_the_present_populations_draws_are_unchanged():
    # the laws of seeds 101-110 as docs/evaluation/population.md lists them
    assert [P.draw(s).law for s in range(101, 111)] == [
        "lugre", "lugre", "lugre", "elasto-plastic", "lugre", "maxwell-slip", "lugre", "lugre", "maxwell-slip",
        "maxwell-slip"]
    before = [P.draw(s) for s in (101, 104, 106)]
    for f in G.FAMILIES:
        for s in G.family_seeds(f, 2):
            G.hoist(f, s)
    assert [P.draw(s) for s in (101, 104, 106)] == before
    assert G.family_seeds("lugre", 4) == [101, 102, 103, 105]
    assert G.hoist("lugre", 101) == P.draw(101)
    with pytest.raises(ValueError):
        G.hoist("maxwell-slip", 101)


def test_a_held_out_hoist_is_the_drawn_one_with_another_seal(tmp_path):
    s = G.family_seeds("dahl", 1)[0]
    h, d = P.draw(s), G.hoist("dahl", s)
    assert d.law == "dahl" and d.friction["law"] == "dahl"
    assert d.friction == P.seal_table("dahl", h.draws, h.friction["force_scale"])
    assert (d.offsets_m, d.groove_creep, d.bore_m, d.hose_scale, d.oil_temp_C, d.payload_kg) == \
        (h.offsets_m, h.groove_creep, h.bore_m, h.hose_scale, h.oil_temp_C, h.payload_kg)
    path = G.scenario_for("dahl", s, tmp_path)
    doc = tomllib.loads(open(path).read())
    assert doc["name"] == f"population-dahl-{s}" and doc["plant"]["friction"] == d.friction
    assert doc["plant"]["ropes"]["offsets_m"] == list(h.offsets_m)
    assert G.scenario_for("lugre", 101, tmp_path) == "population-101"


def test_tuning_hoists_leave_the_family_out():
    for f in G.FAMILIES:
        hs = G.tuning_hoists_for(f)
        assert hs and all(g != f for g, _s in hs) and all(s in P.TUNING_SEEDS for _g, s in hs)
    assert G.settings_seeds_of("dahl") == [] and G.settings_seeds_of("bliman-sorine") == []
    assert sum(len(G.settings_seeds_of(f)) for f in P.LAWS) == len(P.TUNING_SEEDS)


def _arrays(n=600):
    phase = np.full(n, M.CONSTANT_SPEED, np.int8)
    phase[:100] = M.REST_BOTTOM
    phase[100:200] = M.ACCELERATION
    phase[400:500] = M.DECELERATION
    phase[500:] = M.REST_PITHEAD
    truth = np.full((n, 4), 50e3)
    return {"truth": truth, "node": truth.copy(), "raw": truth.copy(), "phase": phase, "keep": np.ones(n, bool)}


def test_an_error_in_one_phase_shows_in_that_phase_only():
    a = _arrays()
    a["node"][100:200, 2] += 800.0          # 1 % of rated on rope 3 while accelerating
    fig = G.wind_figures(a, RATED)["phases"]
    node = fig["node"]
    assert node["acceleration"]["rope_rms_pct"] == pytest.approx(1.0)
    assert node["acceleration"]["per_rope_rms_pct"] == pytest.approx([0.0, 0.0, 1.0, 0.0])
    assert node["acceleration"]["total_rms_pct"] == pytest.approx(0.25)   # of the rated total, 4 x rated
    for p in ("rest-bottom", "constant-speed", "deceleration", "rest-pithead"):
        assert node[p]["rope_rms_pct"] == 0.0
    assert node["reversal-creep"] is None
    assert node[G.WIND]["rope_rms_pct"] == pytest.approx(np.sqrt(100 / 600))
    assert fig["raw"][G.WIND]["rope_rms_pct"] == 0.0


def test_excluded_frames_and_missing_ropes_are_not_scored():
    a = _arrays()
    a["node"][0:50, 0] += 8000.0
    a["keep"][0:50] = False
    a["node"][60, 1] = np.nan
    fig = G.wind_figures(a, RATED)["phases"]["node"]["rest-bottom"]
    assert fig["rope_rms_pct"] == 0.0 and fig["frames"] == 50


def test_do_no_harm_at_each_rest():
    a = _arrays()
    a["raw"][:100] -= 4000.0                 # raw 5 % low on every rope at the bottom
    a["node"][:100, 0] += 400.0              # the node 0.5 % high on rope 1: within raw's error
    a["node"][500:, 3] += 480.0              # 0.6 % on rope 4 at the top, raw exact: harm
    d = G.wind_figures(a, RATED)["do_no_harm"]
    assert d["rest-bottom"]["ok"] and d["rest-bottom"]["excess_pct"] == pytest.approx(0.5 - 5.0)
    top = d["rest-pithead"]
    assert not top["ok"] and not top["ropes_ok"] and top["total_ok"]
    assert top["worst"] == "rope 4" and top["excess_pct"] == pytest.approx(0.6)
    # exactly raw + 0.5 % passes
    assert G.do_no_harm({"total_rms_pct": 0.5, "per_rope_rms_pct": [0.5]},
                        {"total_rms_pct": 0.0, "per_rope_rms_pct": [0.0]})["ok"]
    assert G.do_no_harm(None, {"total_rms_pct": 0.0, "per_rope_rms_pct": [0.0]}) is None


def test_the_family_summary_counts_the_winds_that_do_no_harm():
    def hoist(seed, excess):
        a = _arrays()
        a["node"][500:, 0] += excess * RATED / 100
        return {"family": "dahl", "seed": seed, "hoist": "h", "commissioning": {"seal_refused": None},
                **G.wind_figures(a, RATED)}
    rs = [hoist(1, 0.2), hoist(2, 0.9), hoist(3, 0.0), {"family": "dahl", "seed": 4, "hoist": "h", "refused": "x"}]
    s = G.family_summary(rs)
    top = s["do_no_harm"]["rest-pithead"]
    assert (top["ok"], top["winds"], top["share"]) == (2, 3, 0.667)
    assert top["worst_excess_pct"] == pytest.approx(0.9) and top["worst"] == "seed 2, rope 1"
    assert s["refused"] == [4] and s["scored"] == 3
    assert s["phases"]["rest-pithead"]["node"]["rope_rms_pct"]["max"] == pytest.approx(0.9)
    out = {"seeds": "scoring", "per_family": 4, "wall_s": 1.0, "summary": {"families": {"dahl": {
        **s, "own_tuning_seeds": []}}, "all": s}, "hoists": rs}
    md = G.markdown(out, "ropemon evaluate --leave-one-family-out 4")
    assert md.splitlines()[0] == "Made by `ropemon evaluate --leave-one-family-out 4`"
    assert any(ln.startswith("| Dahl | all scored | 3 of 3 |") and "| 2 of 3 | +0.90 (seed 2, rope 1) |" in ln
               for ln in md.splitlines())
    assert s["accepted"] == [1, 2, 3] and s["do_no_harm_accepted"]["rest-pithead"]["ok"] == 2


def test_a_fit_without_a_static_peak_is_lifted_for_scoring(tmp_path):
    fit = {"Fs": {"intercept": 1400.0, "slope": 800.0}, "Fc": {"intercept": 1200.0, "slope": 900.0},
           "vs": {"intercept": 1e-3, "slope": 0.0}, "sigma2": {"intercept": 1e4, "slope": 0.0},
           "sigma0": 6e7, "sigma1": 6e4, "pressure_range_MPa": [2.0, 12.0]}
    (tmp_path / "friction-abc.json").write_text(json.dumps(fit))
    why = G.lift_fit(fit, tmp_path)
    assert "Fs" in why
    lifted = json.loads((tmp_path / "friction-abc.json").read_text())
    assert lifted["Fs"] == {"intercept": 1400.0, "slope": 900.0} and lifted["Fc"] == fit["Fc"]
    ok = dict(fit, Fs={"intercept": 1400.0, "slope": 950.0})
    assert G.lift_fit(ok, tmp_path) is None


def test_only_a_finished_population_wind_is_reused(tmp_path):
    d = tmp_path / "population-101"
    assert not G.reusable(d)
    (d / "sim").mkdir(parents=True)
    for f in ("frames.bin", "node-evaluated.json", "sim/truth.npz"):
        assert not G.reusable(d)
        (d / f).write_bytes(b"")
    assert G.reusable(d)
