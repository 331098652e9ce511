"""Embedded procedural shape collection: seeded, labelled-part meshes for the paper's 8 categories.

Frame as ShapeNet: y up, bilateral symmetry across x = 0, front along -z. Parts are separate,
overlapping closed meshes (not unioned), like scraped CAD models; a fraction of models carry
deliberate defects (see :mod:`pipeline.shapes.defects`). A fraction of cars, airplanes and
bottles have detached parts, as real models do: wheels clear of the body, engines hanging under
their pylons with a gap, a cap floating above the neck; they stay separate bodies after repair.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from pipeline.core.seeding import rng_for
from pipeline.shapes import airplane, bathtub, bottle, car, guitar, gun, knife, mug
from pipeline.shapes.defects import apply_defects
from pipeline.shapes.model import Cuboid, Part, ProceduralModel, cuboid_of

# Bumped whenever a generator's output changes: it keys the folder the models are written to,
# so a work folder made by an older generator is never read as this one's models. (3: race bodies
# and fighters; 2 was an experiment that did not land, whose folders may linger on a machine.)
# tests/test_shapes_generate.py holds each version's fingerprint and fails when output and version disagree.
SHAPES_VERSION = 3

CATEGORIES = ("airplane", "bathtub", "bottle", "car", "guitar", "gun", "knife", "mug")

# Builders take (rng, detached); those without a detached variant ignore the flag.
_BUILDERS: dict[str, Callable[[np.random.Generator, bool], list[Part]]] = {
    "airplane": airplane.build,
    "bathtub": bathtub.build,
    "bottle": bottle.build,
    "car": car.build,
    "guitar": guitar.build,
    "gun": gun.build,
    "knife": knife.build,
    "mug": mug.build,
}


DETACHABLE = ("airplane", "bottle", "car")


def generate(
    category: str, index: int, seed: int = 0, defect_fraction: float = 0.25, detached_fraction: float = 0.3
) -> ProceduralModel:
    """Model ``index`` of ``category``: same (seed, category, index) gives identical arrays.

    ``detached_fraction``: probability that a model of a DETACHABLE category has detached parts.
    """
    if category not in _BUILDERS:
        raise ValueError(f"unknown category {category!r}; expected one of {CATEGORIES}")
    shape_rng = rng_for(seed, "shapes", category, index)
    # Its own stream, drawn after the shape's, so the attached variant of a shape never changes.
    detached = category in DETACHABLE and rng_for(seed, "shapes-detached", category, index).random() < detached_fraction
    parts = _BUILDERS[category](shape_rng, detached)
    # A separate stream for defects, so changing defect_fraction never changes the clean shape.
    defects = apply_defects(parts, rng_for(seed, "shapes-defects", category, index), defect_fraction)
    cuboids = [cuboid_of(p) for p in parts]
    return ProceduralModel(category, int(index), f"{int(index):05d}", int(seed), parts, cuboids, defects, detached)


__all__ = ["CATEGORIES", "DETACHABLE", "SHAPES_VERSION", "Cuboid", "Part", "ProceduralModel", "generate"]
