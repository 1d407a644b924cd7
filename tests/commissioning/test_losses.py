"""Pipe loss tables: textbook limits, symmetry, temperature, and the table the node gets."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from ropemon.commission import losses
from ropemon.commission.site import Fitting, PipePath, PipeSegment, load_site

ROOT = Path(__file__).resolve().parents[2]
RHO, NU = 870.0, 100e-6  # a VG46-like oil near 20 C


def straight(length_m: float, bore_m: float, roughness_m: float = 0.0) -> PipePath:
    return PipePath(segments=(PipeSegment(length_m, bore_m, roughness_m),), fittings=())


def test_laminar_straight_pipe_is_hagen_poiseuille():
    q = 10 / 60000  # 10 L/min in 10 mm: Re ~ 210
    dp = losses.pressure_loss_Pa(straight(2.0, 0.010), q, RHO, NU)
    expected = 128 * (RHO * NU) * 2.0 * q / (math.pi * 0.010 ** 4)
    assert dp == pytest.approx(expected, rel=1e-9)


def test_turbulent_smooth_pipe_is_close_to_blasius():
    d, q, nu = 0.010, 40 / 60000, 5e-6        # thin oil, Re ~ 17000
    v = q / (math.pi * d * d / 4)
    re = v * d / nu
    assert 4000 < re < 1e5
    blasius = 0.3164 * re ** -0.25 * (1.0 / d) * RHO * v * v / 2
    assert losses.pressure_loss_Pa(straight(1.0, d), q, RHO, nu) == pytest.approx(blasius, rel=0.03)


def test_loss_is_odd_zero_at_rest_and_rises_with_flow():
    pipe = load_site(ROOT / "scenarios" / "paper-site.toml").pipes[0]
    assert losses.pressure_loss_Pa(pipe, 0.0, RHO, NU) == 0.0
    prev = 0.0
    for lpm in (1, 2, 5, 10, 20, 30):
        q = lpm / 60000
        dp = losses.pressure_loss_Pa(pipe, q, RHO, NU)
        assert dp > prev
        assert losses.pressure_loss_Pa(pipe, -q, RHO, NU) == -dp
        prev = dp


def test_laminar_fittings_cost_more_than_their_turbulent_K():
    for f in (Fitting("bend", 0.010), Fitting("tee", 0.010, flow="branch"), Fitting("valve", 0.010, valve="ball"),
              Fitting("contraction", 0.010, from_bore_m=0.016)):
        assert losses.fitting_K(f, 200.0, 150.0) > 2 * losses.fitting_K(f, 1e6, 1e6), f.kind
    assert losses.fitting_K(Fitting("custom", 0.01, K=1.7), 10.0, 10.0) == 1.7


def test_expansion_K_is_referred_to_the_outlet():
    f = Fitting("expansion", 0.020, from_bore_m=0.010)
    k_out = losses.fitting_K(f, 1e5, 2e5)
    # Borda-Carnot at the inlet velocity: (1 - (d1/d2)^2)^2 = 0.5625, times (A_out/A_in)^2 = 16
    assert k_out == pytest.approx(0.5625 * 16, rel=0.02)


def test_paper_site_table_shape_temperatures_and_magnitude():
    site = load_site(ROOT / "scenarios" / "paper-site.toml")
    t = losses.loss_table(site)
    ropes, temps, flows = len(t["dp_Pa"]), len(t["temps_C"]), len(t["flow_m3_s"])
    assert (ropes, temps, flows) == (4, len(site.oil.table_temps_C), losses.FLOW_POINTS)
    assert t["flow_m3_s"][0] == 0.0
    assert t["flow_m3_s"][-1] == pytest.approx(site.cylinders[0].area_m2 * site.cylinders[0].max_speed_m_s)
    for rope in t["dp_Pa"]:
        for cold, warm in zip(rope, rope[1:]):  # temps ascend: warmer oil, less loss
            assert all(w < c for c, w in zip(cold[1:], warm[1:]))
    # laminar hose flow: the loss changes several-fold between a winter and a summer shaft
    assert t["dp_Pa"][0][0][-1] / t["dp_Pa"][0][-1][-1] > 5
    # the paper's cylinder lost 0.26 MPa at 20 L/min; the example hoses are of that order
    i20 = t["temps_C"].index(20.0)
    oil = site.oil.properties()
    dp20 = losses.pressure_loss_Pa(site.pipes[0], 20 / 60000, float(oil.rho_kg_m3(20.0)), float(oil.nu_m2_s(20.0)))
    assert 0.1e6 < dp20 < 1.0e6
    assert t["dp_Pa"][0][i20][-1] > dp20 * 0.9  # table top (23.6 L/min) above the 20 L/min value


def test_oil_comes_from_the_plant_oil_model():
    site = load_site(ROOT / "scenarios" / "paper-site.toml")
    oil = site.oil.properties()
    assert float(oil.nu_m2_s(40.0)) * 1e6 == pytest.approx(46.0, rel=1e-6)
    assert float(oil.nu_m2_s(100.0)) * 1e6 == pytest.approx(6.8, rel=1e-6)


def test_table_resolution_is_fine_enough_for_linear_interpolation():
    # the node interpolates linearly between table flows: between two points it must stay
    # within 1 % of the largest loss of the table, at every temperature
    site = load_site(ROOT / "scenarios" / "paper-site.toml")
    t = losses.loss_table(site)
    oil = site.oil.properties()
    flows = t["flow_m3_s"]
    for i_t, temp in enumerate(t["temps_C"]):
        rho, nu = float(oil.rho_kg_m3(temp)), float(oil.nu_m2_s(temp))
        row = t["dp_Pa"][0][i_t]
        for j in range(len(flows) - 1):
            q = 0.5 * (flows[j] + flows[j + 1])
            exact = losses.pressure_loss_Pa(site.pipes[0], q, rho, nu)
            assert abs(0.5 * (row[j] + row[j + 1]) - exact) < 0.01 * row[-1]
