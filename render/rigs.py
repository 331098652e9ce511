"""Camera rigs: where the cameras of one model stand, as (azimuth, elevation) pairs in degrees.

Each rig is one function in ``RIGS``, registered with ``@register_rig("name")``; the function
gets ``(settings, seed, category, model_id, vertices)`` (``vertices``: the (n, 3) mesh the views
will draw, unit radius, centred) and returns the model's (azimuth_deg, elevation_deg) list. ``RenderSettings`` accepts exactly the registered names and ``render.cameras.rig`` turns the
pairs into cameras, so a new rig is one decorated function in this file.

This module imports nothing heavier than numpy at load time: ``render.settings`` reads ``RIGS``
and is imported inside Blender too.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable

import numpy as np

if TYPE_CHECKING:
    from render.settings import RenderSettings

RigFn = Callable[["RenderSettings", int, str, str, np.ndarray], list[tuple[float, float]]]
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


def seeded_views(
    settings: RenderSettings, seed: int, category: str, model_id: str, n: int
) -> list[tuple[float, float]]:
    """``n`` seeded (azimuth over 360°, elevation uniform in ``elevation_range``) pairs."""
    from pipeline.core.seeding import rng_for

    rng = rng_for(seed, "render", category, model_id)
    lo, hi = settings.elevation_range
    az = rng.uniform(0.0, 360.0, n)
    el = rng.uniform(lo, hi, n)
    # Round so the values survive a JSON round trip unchanged (same floats in Blender and on disk).
    return [(round(float(a), 6), round(float(e), 6)) for a, e in zip(az, el)]


@register_rig("random")
def random_rig(
    settings: RenderSettings, seed: int, category: str, model_id: str, vertices: np.ndarray
) -> list[tuple[float, float]]:
    """``views`` cameras at seeded azimuths over 360° and elevations drawn uniformly from
    ``elevation_range``, seeded by (seed, "render", category, model_id) only."""
    return seeded_views(settings, seed, category, model_id, settings.views)


def silhouette_extent(settings: RenderSettings, vertices: np.ndarray, azimuth: float, elevation: float) -> float:
    """Longer side of the box of the model's projection, as a share of the frame: the extent of
    its silhouette, and so of the drawing's ink."""
    return silhouette_extents(settings, vertices, [(azimuth, elevation)])[0]


def _projected(settings: RenderSettings, vertices: np.ndarray, pairs: list[tuple[float, float]]) -> np.ndarray:
    """Pixel coordinates ``(N, P, 2)`` of the vertices in every view of ``pairs``, all views
    projected in one product (the same numbers as ``render.cameras.project`` view by view)."""
    from render.cameras import make_view

    points = np.asarray(vertices, float)
    homogeneous = np.c_[points, np.ones(len(points))]
    projections = np.concatenate([np.asarray(make_view(settings, a, e).projection, float) for a, e in pairs])
    h = (homogeneous @ projections.T).reshape(len(points), len(pairs), 3)
    return h[:, :, :2] / h[:, :, 2:3]


def _extents(settings: RenderSettings, uv: np.ndarray) -> list[float]:
    # clipping is monotone, so the clipped box is the box clipped: two values a view, not all
    lo, hi = (np.clip(x, 0.0, settings.image_size) for x in (uv.min(axis=0), uv.max(axis=0)))
    return ((hi - lo).max(axis=1) / settings.image_size).tolist()


def silhouette_extents(settings: RenderSettings, vertices: np.ndarray, pairs: list[tuple[float, float]]) -> list[float]:
    """:func:`silhouette_extent` of every (azimuth, elevation) in ``pairs``, all views projected
    in one product (in half the time of 32 separate calls)."""
    return _extents(settings, _projected(settings, vertices, pairs))


def silhouette_hull_areas(
    settings: RenderSettings, vertices: np.ndarray, pairs: list[tuple[float, float]]
) -> list[float]:
    """Area of the convex hull of the model's projection in each view of ``pairs``, as a share of
    the frame: how much of the model a view shows face-on. An airplane seen from the side, its
    wings edge-on, spans the frame but covers a thin strip of it."""
    import cv2
    from scipy.spatial import ConvexHull, QhullError  # only when asked for: the worker starts without scipy

    points = np.asarray(vertices, float)
    # a perspective projection maps the solid hull onto the hull of the projection: project its
    # few hundred corners, not every vertex (all of them when the points span no volume)
    try:
        corners = points[ConvexHull(points).vertices]
    except (QhullError, ValueError):
        corners = points
    uv = np.clip(_projected(settings, corners, pairs), 0.0, settings.image_size).astype(np.float32)
    frame = float(settings.image_size) ** 2
    return [float(cv2.contourArea(cv2.convexHull(np.ascontiguousarray(uv[:, i])))) / frame for i in range(len(pairs))]


@register_rig("representative")
def representative_rig(
    settings: RenderSettings, seed: int, category: str, model_id: str, vertices: np.ndarray
) -> list[tuple[float, float]]:
    """Random views (as "random") that show the model: of ``view_candidates`` seeded draws, the
    first ``views`` whose silhouette spans at least ``min_view_extent`` of the frame and
    ``view_extent_fraction`` of the widest candidate's; a view down a knife's blade, a blob a
    tenth of the frame wide, is never drawn. With ``view_area_fraction`` > 0 a kept view's
    silhouette hull also covers that share of the largest candidate's (an airplane's wings not
    edge-on). When too few pass, the widest (the largest, by area) of the rest fill up."""
    pairs = seeded_views(settings, seed, category, model_id, max(settings.view_candidates, settings.views))
    uv = _projected(settings, vertices, pairs)
    extent = _extents(settings, uv)
    floor = max(settings.min_view_extent, settings.view_extent_fraction * max(extent))
    shows = [e >= floor for e in extent]
    order = extent  # the fill-up's: widest first
    if settings.view_area_fraction > 0:
        area = silhouette_hull_areas(settings, vertices, pairs)
        shows = [ok and a >= settings.view_area_fraction * max(area) for ok, a in zip(shows, area)]
        order = area
    kept = [i for i in range(len(pairs)) if shows[i]][: settings.views]
    if len(kept) < settings.views:
        rest = sorted((i for i in range(len(pairs)) if i not in kept), key=lambda i: (-order[i], i))
        kept += rest[: settings.views - len(kept)]
    return [pairs[i] for i in kept]


@register_rig("front_side_top")
def front_side_top_rig(
    settings: RenderSettings, seed: int, category: str, model_id: str, vertices: np.ndarray
) -> list[tuple[float, float]]:
    """Three fixed cameras: front, side (+x), top (+y); ``views`` is ignored."""
    return list(FRONT_SIDE_TOP)
