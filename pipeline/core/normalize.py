"""Normalization into the unit sphere: bounding-box centre to the origin, farthest vertex at 1."""

from __future__ import annotations

import numpy as np


def unit_sphere_transform(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (3,) and scale such that (v - centre) / scale has its farthest vertex at radius 1."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    center = (lo + hi) / 2.0
    scale = float(np.linalg.norm(vertices - center, axis=1).max())
    if not scale > 0:
        raise ValueError("cannot normalize a mesh whose vertices all coincide")
    return center, scale


def apply_transform(points: np.ndarray, center: np.ndarray, scale: float) -> np.ndarray:
    """Map source-frame points into the normalized frame."""
    return (np.asarray(points, dtype=np.float64) - center) / scale


def transform_box(lo: np.ndarray, hi: np.ndarray, center: np.ndarray, scale: float) -> tuple[list, list]:
    """An axis-aligned box's corners in the normalized frame (the transform is a uniform scale)."""
    return apply_transform(lo, center, scale).tolist(), apply_transform(hi, center, scale).tolist()
