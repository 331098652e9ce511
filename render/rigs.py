"""Camera rigs: where the cameras of one model stand, as (azimuth, elevation) pairs in degrees.

Each rig is one function in ``RIGS``, registered with ``@register_rig("name")``; the function
gets ``(settings, seed, category, model_id)`` and returns the model's (azimuth_deg, elevation_deg)
list. ``RenderSettings`` accepts exactly the registered names and ``render.cameras.rig`` turns the
pairs into cameras, so a new rig is one decorated function in this file.

This module imports nothing heavy at load time: ``render.settings`` reads ``RIGS`` and is
imported inside Blender too.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable

if TYPE_CHECKING:
    from render.settings import RenderSettings

RigFn = Callable[["RenderSettings", int, str, str], list[tuple[float, float]]]
RIGS: dict[str, RigFn] = {}

# (azimuth, elevation) of the fixed rig; the top view is looked at from +y.
FRONT_SIDE_TOP = ((0.0, 0.0), (90.0, 0.0), (0.0, 90.0))


def register_rig(name: str) -> Callable[[RigFn], RigFn]:
    """Decorator adding a rig under a new ``name``."""
    def add(fn: RigFn) -> RigFn:
        if name in RIGS:
            raise ValueError(f"camera rig {name!r} is already registered")
        RIGS[name] = fn
        return fn
    return add


@register_rig("random")
def random_rig(settings: RenderSettings, seed: int, category: str, model_id: str) -> list[tuple[float, float]]:
    """``views`` cameras at seeded azimuths over 360° and elevations drawn uniformly from
    ``elevation_range``, seeded by (seed, "render", category, model_id) only."""
    from pipeline.core.seeding import rng_for

    rng = rng_for(seed, "render", category, model_id)
    lo, hi = settings.elevation_range
    az = rng.uniform(0.0, 360.0, settings.views)
    el = rng.uniform(lo, hi, settings.views)
    # Round so the values survive a JSON round trip unchanged (same floats in Blender and on disk).
    return [(round(float(a), 6), round(float(e), 6)) for a, e in zip(az, el)]


@register_rig("front_side_top")
def front_side_top_rig(settings: RenderSettings, seed: int, category: str, model_id: str) -> list[tuple[float, float]]:
    """Three fixed cameras: front, side (+x), top (+y); ``views`` is ignored."""
    return list(FRONT_SIDE_TOP)
