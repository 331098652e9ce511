"""One view's vector strokes → K sketch variants (augmented strokes + pencil raster), seeded."""

from __future__ import annotations

import dataclasses

import numpy as np

from augment.pencil import draw_pencil
from augment.settings import REFERENCE_SIZE, AugmentSettings
from augment.shading import tone_strokes
from augment.strokes import augment_strokes, resample_strokes
from pipeline.core.seeding import rng_for


@dataclasses.dataclass
class Variant:
    width: float  # nominal line width, output pixels
    strokes: list[np.ndarray]  # augmented strokes, output pixels
    image: np.ndarray  # (out_size, out_size) uint8


def reference_strokes(strokes: list[np.ndarray], source_size: int, settings: AugmentSettings) -> list[np.ndarray]:
    """Vectorized strokes (source-image px) → smooth dense curves on the reference canvas."""
    to_ref = REFERENCE_SIZE / float(source_size)
    return resample_strokes([np.asarray(s, np.float64) * to_ref for s in strokes], settings.resample_spacing)


def make_variant(ref: list[np.ndarray], settings: AugmentSettings, variant: int, key: tuple) -> Variant:
    """Variant ``variant`` of one view from its ``reference_strokes``; ``key`` = (seed, category,
    model_id, view) seeds it.

    Strokes and raster draw from separate keyed generators, so a change to the rasterizer
    leaves the vector strokes of a variant unchanged.
    """
    seed, category, model_id, view = key
    to_out = settings.out_size / float(REFERENCE_SIZE)
    aug = augment_strokes(ref, rng_for(seed, "augment", category, model_id, view, variant), settings)
    out = [s * to_out for s in aug]
    width = settings.width_for(variant) * to_out
    share = settings.shading_for(variant)
    offset = (settings.shade_offset[0] * to_out, settings.shade_offset[1] * to_out)
    tone = (
        tone_strokes(out, rng_for(seed, "shading", category, model_id, view, variant), share, offset) if share else []
    )
    image = draw_pencil(
        out,
        settings.out_size,
        width,
        rng_for(seed, "pencil", category, model_id, view, variant),
        settings,
        settings.tones_for(variant),
        tone,
    )
    return Variant(width=width, strokes=out, image=image)


def view_variants(strokes: list[np.ndarray], source_size: int, settings: AugmentSettings, key: tuple) -> list[Variant]:
    """The ``settings.variants`` variants of one view."""
    ref = reference_strokes(strokes, source_size, settings)
    return [make_variant(ref, settings, k, key) for k in range(settings.variants)]
