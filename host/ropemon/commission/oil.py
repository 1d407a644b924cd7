"""Hydraulic oil properties against temperature: Walther (ASTM D341) viscosity, linear density.

One model of oil for the site description (SITE.toml's grade, the pipe-loss table) and
the simulator: the plant's oil is the *actual* oil in the cylinders and may differ from
what the site assumes (a different brand of the grade, another 100 C viscosity), which is
one of the hidden truths a scenario can set.
"""
from __future__ import annotations

import math

import numpy as np
from dataclasses import dataclass

# Typical 100 C kinematic viscosity (cSt) of a VI ~100 mineral oil of each ISO VG grade.
VG_CST_100C = {10: 2.6, 15: 3.4, 22: 4.3, 32: 5.4, 46: 6.8, 68: 8.7, 100: 11.1, 150: 14.7}
DENSITY_PER_C = 6.5e-4  # relative density decrease per C (mineral oil)


@dataclass(frozen=True)
class Oil:
    """An oil by its ISO VG grade (cSt at 40 C), its 100 C viscosity and its 15 C density."""

    iso_vg: float
    cst_100C: float
    density_15C_kg_m3: float = 870.0

    @classmethod
    def grade(cls, iso_vg: int, cst_100C: float | None = None, density_15C_kg_m3: float = 870.0) -> "Oil":
        if cst_100C is None:
            if iso_vg not in VG_CST_100C:
                raise ValueError(f"iso_vg: no typical 100 C viscosity for grade {iso_vg}; give cst_100C")
            cst_100C = VG_CST_100C[iso_vg]
        return cls(float(iso_vg), float(cst_100C), float(density_15C_kg_m3))

    def walther(self) -> tuple[float, float]:
        """(A, B) of log10 log10(nu_cSt + 0.7) = A - B log10(T_K) through (40 C, VG) and (100 C, cst_100C)."""
        y1 = math.log10(math.log10(self.iso_vg + 0.7))
        y2 = math.log10(math.log10(self.cst_100C + 0.7))
        x1, x2 = math.log10(313.15), math.log10(373.15)
        b = (y1 - y2) / (x2 - x1)
        return y1 + b * x1, b

    def nu_m2_s(self, temp_C: float) -> float:
        """Kinematic viscosity (m^2/s); temp_C may be an array."""
        a, b = self.walther()
        return (10 ** (10 ** (a - b * np.log10(np.asarray(temp_C) + 273.15))) - 0.7) * 1e-6

    def rho_kg_m3(self, temp_C: float) -> float:
        return self.density_15C_kg_m3 * (1.0 - DENSITY_PER_C * (np.asarray(temp_C) - 15.0))

    def mu_Pa_s(self, temp_C: float) -> float:
        """Dynamic viscosity (Pa s)."""
        return self.nu_m2_s(temp_C) * self.rho_kg_m3(temp_C)
