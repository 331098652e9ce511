"""Loss weights with the paper's values for unit-sphere models; a weight of 0 switches a term off."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LossWeights:
    chamfer: float = 1.0
    normal: float = 0.008
    flat: float = 2.0
    collision: float = 1e-5
    template_normal: float = 1e-4
    symmetry: float = 1.0
    collision_eps: float = 1e-6  # ε of the smooth indicator, in squared-distance units
