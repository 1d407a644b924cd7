"""`ropemon study pithead-bound`: the least spread of the pithead total the pressure noise allows."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ropemon import cli
from ropemon.lab import evaluate as EV
from ropemon.lab.plant.friction import from_table
from ropemon.lab.rundir import RunDir
from ropemon.lab.studies import pithead_bound as pb

# the paper hoist's seal (scenarios/paper-field-trip.toml)
SEAL = from_table({"law": "lugre", "Fs": {"intercept": 2500.0, "slope": 2000.0},
                   "Fc": {"intercept": 1700.0, "slope": 1200.0}, "vs": {"intercept": 0.004, "slope": -0.0001},
                   "sigma2": {"intercept": 20000.0, "slope": 2000.0}, "sigma0": 1e8, "sigma1": 5e4}, "seal")


def test_seal_friction_is_the_laws_own_state_equation_solved():
    # a slide, a stop and a decaying bounce of a few um, at 5.5 MPa: the exact per-sample
    # solution against an accurate ODE solution of the same law on the same path
    hz = 200
    t = np.arange(0, 4.0, 1 / hz)
    x = np.where(t < 1.0, 200e-6 * t, 200e-6) + 3e-6 * np.exp(-(t - 1) / 0.8) * np.sin(2 * np.pi * 2.6 * t) * (t >= 1)
    x = np.stack([x, -x], axis=1)
    p = np.full_like(x, 5.5e6)
    got = pb.seal_friction(SEAL, x, p, np.zeros(2), hz)

    def rhs(tt, z):
        i = min(int(tt * hz), len(t) - 2)
        v = (x[i + 1] - x[i]) * hz
        return SEAL.evaluate(v, z, p[i]).zdot

    sol = solve_ivp(rhs, (0, t[-1]), np.zeros(2), t_eval=t, max_step=0.2 / hz, rtol=1e-9, atol=1e-13)
    z = sol.y.T
    v = np.vstack([np.diff(x, axis=0) * hz, np.zeros((1, 2))])
    want = SEAL.evaluate(v, z, p).F
    fs = 2500 + 2000 * 5.5
    assert np.abs(got - want).max() < 0.002 * fs
    assert np.allclose(got[:, 0], -got[:, 1])  # odd in the path, as the law is
    # the slide reaches the Stribeck level, the bounce then relaxes it
    assert 0.9 * (1700 + 1200 * 5.5) < got[190, 0] < 1.05 * fs
    assert got[-1, 0] < got[199, 0] - 100


def test_scale_sd_is_the_least_squares_spread():
    # the scale of a known waveform read by least squares from the mean of four channels
    # of unequal noise: its sd over many draws is the bound's
    rng = np.random.default_rng(7)
    hz = 200
    t = np.arange(0, 5.0, 1 / hz)
    shape = 1500.0 * np.exp(-t / 2) * np.sin(2 * np.pi * 2.6 * t)
    sig = np.array([5e3, 4e3, 6e3, 5e3])
    est = []
    for _ in range(2000):
        y = (shape[:, None] + rng.normal(0.0, sig, (len(t), 4))).mean(axis=1)
        est.append((y @ shape) / (shape @ shape))
    want = pb.scale_sd(shape, sig)
    assert np.std(est) == pytest.approx(want, rel=0.06)
    assert pb.scale_sd(shape, sig / 2) == pytest.approx(want / 2)
    assert pb.scale_sd(np.zeros(5), sig) == math.inf
    # with two displacement channels reading their own waveforms as well: the weighted
    # least squares of all six channels
    xs = np.stack([shape * 2e-9, -shape * 1e-9], axis=1)   # m
    xsig = np.array([2e-6, 1e-6])
    est = []
    for _ in range(2000):
        y = (shape[:, None] + rng.normal(0.0, sig, (len(t), 4))).mean(axis=1)
        yx = xs + rng.normal(0.0, xsig, xs.shape)
        w = 16 / (sig ** 2).sum()
        est.append((w * (y @ shape) + ((yx * xs).sum(0) / xsig ** 2).sum())
                   / (w * (shape @ shape) + ((xs ** 2).sum(0) / xsig ** 2).sum()))
    both = pb.scale_sd(shape, sig, xs, xsig)
    assert both < 0.9 * want  # these displacement channels are made informative
    assert np.std(est) == pytest.approx(both, rel=0.06)


def test_outside_and_combined():
    assert pb.outside(0.3) == pytest.approx(0.3173, abs=1e-4)  # one sd: 31.7 % beyond
    assert pb.outside(0.1) == pytest.approx(0.0027, abs=1e-4)
    assert pb.outside(0.0) == 0.0
    eps = [pb.Episode(slice(0, 1), 1.0, 0.1, 0.3), pb.Episode(slice(1, 2), 0.0, math.inf, math.nan),
           pb.Episode(slice(2, 3), 1.0, 0.1, -0.4)]
    assert pb.combined_sd(eps) == pytest.approx(0.5)


def test_on_the_short_wind(tmp_path, capsys):
    run = tmp_path / "short-test"
    EV.simulate("short-test", run / "sim", 1)
    r = pb.load(RunDir(run))
    # the records carry the site's noise (5 kPa and the ADC's), measured per channel
    assert np.all((r.channel_noise_pa > 4.9e3) & (r.channel_noise_pa < 5.5e3))
    # 20 um, and the 10.4 um counts' rounding
    assert np.all((r.channel_noise_m > 19e-6) & (r.channel_noise_m < 23e-6))
    # one episode: from the final stop to the end of the scored rest (no payload change)
    assert len(r.episodes) == 1 and r.episodes[0].start == r.stop
    assert r.scored[r.episodes[0].stop - 1] and not r.scored[r.episodes[0].stop:].any()
    eps, check = pb.bound(r)
    half, _ = pb.bound(r, 0.5)
    e, h = eps[0], half[0]
    assert e.amplitude_um > 1.0 and 0 < e.scale_sd < 0.5
    # re-running the true path gives back the truth's friction (to 0.005 % of the total,
    # a few N: the plant's own solver differs a little; common to both scaled runs)
    assert 0 < check < 0.01
    # half the noise: half the scale's sd and, linear in it, half the effect
    assert h.scale_sd == pytest.approx(e.scale_sd / 2)
    assert h.total_sd_pct == pytest.approx(e.total_sd_pct / 2, rel=0.05)
    assert cli.main(["study", "pithead-bound", str(run), "--scale", "1,0.5"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split(" | ")[1] for line in out if line.startswith("| short-test")] == ["x1", "x0.5"]
