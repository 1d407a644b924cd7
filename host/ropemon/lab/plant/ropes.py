"""Head and tail ropes: stiffness and damping against hanging length, hanging masses.

Each head rope is a spring-damper from the wheel to its cylinder's rod: stiffness
k = EA / L with L = headframe height + wheel depth (the rope hanging below the
wheel), damping c = 2 zeta sqrt(k m_share) for a given modal damping ratio of the
rope-cage bounce. A third of each head rope's mass moves with the cage (the
classical Rayleigh correction for a spring's own mass); tail ropes hang below
the cage down to their loop, so their weight on the cage falls as it descends.
Rope paid out over the wheel enters unstretched (an approximation: strain ~1e-3).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class HeadRopes:
    EA_N: float
    kg_per_m: float
    headframe_m: float        # rope length from the wheel to the cage at the pithead landing (depth 0)
    damping_ratio: float
    offsets_m: tuple[float, ...]  # effective length excess of each rope (groove wear, stretch)

    def length_m(self, wheel_depth_m):
        return self.headframe_m + np.asarray(wheel_depth_m)

    def stiffness(self, wheel_depth_m):
        return self.EA_N / self.length_m(wheel_depth_m)


@dataclass(frozen=True)
class TailRopes:
    count: int
    kg_per_m: float
    loop_depth_m: float       # depth of the loop below the pithead landing: hanging length = loop - depth

    def hanging_kg(self, cage_depth_m):
        return self.count * self.kg_per_m * np.maximum(self.loop_depth_m - np.asarray(cage_depth_m), 0.0)
