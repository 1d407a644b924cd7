"""`ropemon bench plant`: the plant simulator's figures (ropemon.lab.plant.bench measures them)."""
from __future__ import annotations

from ropemon.lab.plant.bench import describe, measure

__all__ = ["measure", "describe"]
