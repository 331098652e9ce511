"""Loss weights with the paper's values for unit-sphere models; a weight of 0 switches a term off."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace


@dataclass(frozen=True)
class LossWeights:
    chamfer: float = 1.0
    normal: float = 0.008
    flat: float = 2.0
    collision: float = 1.0  # our L_coll is a penetration depth (docs/geometry.md), not the paper's indicator (1e-5)
    template_normal: float = 1e-4
    symmetry: float = 1.0


def template_weights(regularizers: dict[str, float], overrides: dict[str, float] | None = None) -> LossWeights:
    """The paper's weights with the regularizers a template file names (``Template.regularizers``;
    ``template_normal`` and ``symmetry`` are off unless named), then ``overrides`` (command line)."""
    base = replace(LossWeights(), **{"template_normal": 0.0, "symmetry": 0.0, **regularizers})
    names = {f.name for f in fields(LossWeights)}
    unknown = set(overrides or {}) - names
    if unknown:
        raise ValueError(f"unknown loss weights {sorted(unknown)}")
    return replace(base, **(overrides or {}))
