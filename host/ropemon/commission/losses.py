"""Pressure loss between a cylinder cavity and its sensor tap, and the oil properties it needs.

Along-pipe loss is Darcy-Weisbach with `fluids.friction_factor` (64/Re when
laminar, Clamond's Colebrook solution when turbulent); local losses use Re-aware
loss coefficients (Hooper's 2-K method for bends, tees and valves, Hooper's
sudden contraction/expansion), because hose flow of hydraulic oil is laminar and
constant turbulent K values would be several times too small there. The host
computes tables dp_Pa[rope][temp][flow] here; the node only interpolates them
(docs/config.md, `loss`).

Oil viscosity and density against temperature come from the one oil model,
ropemon.commission.oil (Walther / ASTM D341 through the 40 C and 100 C viscosities).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import fluids
import fluids.fittings as fittings

if TYPE_CHECKING:
    from ropemon.commission.site import Fitting, PipePath, Site

INCH_M = 0.0254

# Hooper 2-K names in fluids for each fitting the site file can name.
_HOOPER_BENDS = {
    (90.0, "standard"): "Elbow, 90°, Standard (R/D = 1), Screwed",
    (90.0, "long"): "Elbow, 90°, Long-radius (R/D = 1.5), All types",
    (45.0, "standard"): "Elbow, 45°, Standard (R/D = 1), All types",
    (45.0, "long"): "Elbow, 45°, Long-radius (R/D 1.5), All types",
    (180.0, "long"): "Elbow, 180°, Long-radius (R/D = 1.5), All types",
}
_HOOPER_TEES = {
    "run": "Tee, Run, Screwed",
    "branch": "Elbow, Used as, Standard, Screwed",  # a tee with the flow turning into the branch
}
_HOOPER_VALVES = {
    "ball": "Valve, Ball, Reduced trim, Beta = 0.9",
    "gate": "Valve, Gate, Full line size, Beta = 1",
    "globe": "Valve, Globe, Standard",
    "plug": "Valve, Plug, Reduced trim, Beta = 0.8",
    "butterfly": "Valve, Butterfly,",
    "check-swing": "Valve, Check, Swing",
    "check-lift": "Valve, Check, Lift",
}

FLOW_POINTS = 17  # flow grid of the node's table: 0 .. Q_max in 16 equal steps


# ---------------------------------------------------------------- one pipe path


def _area(d: float) -> float:
    return math.pi * d * d / 4


def fitting_K(f: "Fitting", Re: float, Re_from: float) -> float:
    """Loss coefficient of a fitting, referred to the velocity in f.bore_m.

    Re is the Reynolds number in f.bore_m; Re_from the one in f.from_bore_m
    (contraction/expansion only).
    """
    if f.kind == "custom":
        return f.K
    if f.kind == "contraction":
        # Hooper: Re of the larger upstream pipe, K in terms of the smaller outlet (bore_m).
        return fittings.contraction_sharp(f.from_bore_m, f.bore_m, Re=Re_from, method="Hooper")
    if f.kind == "expansion":
        # Hooper: Re and K both of the smaller upstream pipe; refer K to the outlet velocity.
        k_from = fittings.diffuser_sharp(f.from_bore_m, f.bore_m, Re=Re_from, method="Hooper")
        return k_from * (f.bore_m / f.from_bore_m) ** 4
    if f.kind == "bend":
        name = _HOOPER_BENDS[(f.angle_deg, f.style)]
    elif f.kind == "tee":
        name = _HOOPER_TEES[f.flow]
    elif f.kind == "valve":
        name = _HOOPER_VALVES[f.valve]
    else:  # pragma: no cover - the site loader refuses other kinds
        raise ValueError(f"unknown fitting kind {f.kind!r}")
    return fittings.Hooper2K(Di=f.bore_m / INCH_M, Re=Re, name=name)


def pressure_loss_Pa(pipe: "PipePath", flow_m3_s: float, rho: float, nu: float) -> float:
    """Pressure drop (Pa) from cavity to tap at a flow (m^3/s); odd in the flow."""
    q = abs(flow_m3_s)
    if q == 0.0:
        return 0.0
    dp = 0.0
    for s in pipe.segments:
        v = q / _area(s.bore_m)
        re = fluids.Reynolds(V=v, D=s.bore_m, nu=nu)
        fd = fluids.friction_factor(Re=re, eD=s.roughness_m / s.bore_m)
        dp += fd * s.length_m / s.bore_m * rho * v * v / 2
    for f in pipe.fittings:
        v = q / _area(f.bore_m)
        re = v * f.bore_m / nu
        d_from = f.from_bore_m or f.bore_m
        re_from = (q / _area(d_from)) * d_from / nu
        dp += fitting_K(f, re, re_from) * rho * v * v / 2
    return math.copysign(dp, flow_m3_s)


# ---------------------------------------------------------------- the node's table


def max_flow_m3_s(site: "Site") -> float:
    """Largest flow out of any cavity: piston area x the site's maximum piston speed."""
    return max(c.area_m2 * c.max_speed_m_s for c in site.cylinders)


def loss_table(site: "Site", flow_points: int = FLOW_POINTS) -> dict[str, Any]:
    """`loss` of the physical config: {"temps_C", "flow_m3_s", "dp_Pa"[rope][temp][flow]} for flow >= 0."""
    q_max = max_flow_m3_s(site)
    flows = [q_max * i / (flow_points - 1) for i in range(flow_points)]
    temps = list(site.oil.table_temps_C)
    oil = site.oil.properties()
    props = [(float(oil.rho_kg_m3(t)), float(oil.nu_m2_s(t))) for t in temps]
    dp = [[[pressure_loss_Pa(pipe, q, rho, nu) for q in flows] for rho, nu in props] for pipe in site.pipes]
    return {"temps_C": temps, "flow_m3_s": flows, "dp_Pa": dp}
