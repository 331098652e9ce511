"""Embedded procedural shape collection: seeded, labelled-part meshes for the paper's 8 categories.

Frame as ShapeNet: y up, bilateral symmetry across x = 0, front along -z. Parts are separate,
overlapping closed meshes (not unioned), like scraped CAD models; a fraction of models carry
deliberate defects (see :mod:`pipeline.shapes.defects`).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from pipeline.seeding import rng_for
from pipeline.shapes import airplane, bathtub, bottle, car, guitar, gun, knife, mug
from pipeline.shapes.defects import apply_defects
from pipeline.shapes.model import Cuboid, Part, ProceduralModel, cuboid_of

CATEGORIES = ("airplane", "bathtub", "bottle", "car", "guitar", "gun", "knife", "mug")

_BUILDERS: dict[str, Callable[[np.random.Generator], list[Part]]] = {
    "airplane": airplane.build,
    "bathtub": bathtub.build,
    "bottle": bottle.build,
    "car": car.build,
    "guitar": guitar.build,
    "gun": gun.build,
    "knife": knife.build,
    "mug": mug.build,
}


def generate(category: str, index: int, seed: int = 0, defect_fraction: float = 0.25) -> ProceduralModel:
    """Model ``index`` of ``category``: same (seed, category, index) gives identical arrays."""
    if category not in _BUILDERS:
        raise ValueError(f"unknown category {category!r}; expected one of {CATEGORIES}")
    shape_rng = rng_for(seed, "shapes", category, index)
    parts = _BUILDERS[category](shape_rng)
    # A separate stream for defects, so changing defect_fraction never changes the clean shape.
    defects = apply_defects(parts, rng_for(seed, "shapes-defects", category, index), defect_fraction)
    cuboids = [cuboid_of(p) for p in parts]
    return ProceduralModel(category, int(index), f"{int(index):05d}", int(seed), parts, cuboids, defects)


__all__ = ["CATEGORIES", "Cuboid", "Part", "ProceduralModel", "generate"]
