"""Polyline geometry: arc length, smoothing, simplification and smooth (Catmull-Rom) resampling.

Every function takes and returns float (K, 2) arrays of (u, v) points and never mutates its input.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter1d


def cumulative_length(points: np.ndarray) -> np.ndarray:
    """Arc length at each vertex (first is 0)."""
    if len(points) < 2:
        return np.zeros(len(points))
    if type(points) is np.ndarray and points.dtype == np.float64:
        # called thousands of times per model on short strokes: the same sums with fewer
        # temporaries (np.diff and np.concatenate cost more than the arithmetic here)
        out = np.zeros(len(points))
        d = points[1:] - points[:-1]
        np.cumsum(np.hypot(d[:, 0], d[:, 1]), out=out[1:])
        return out
    d = np.diff(points, axis=0)
    return np.concatenate([[0.0], np.cumsum(np.hypot(d[:, 0], d[:, 1]))])


def polyline_length(points: np.ndarray) -> float:
    return float(cumulative_length(points)[-1]) if len(points) > 1 else 0.0


def dedupe(points: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Drop consecutive repeated points (they give zero-length segments and NaN tangents)."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return points
    keep = np.empty(len(points), bool)
    keep[0] = True
    if points.ndim == 2 and points.shape[1] == 2:  # the usual (K, 2): same test, fewer temporaries
        d = np.abs(points[1:] - points[:-1])
        np.greater(np.maximum(d[:, 0], d[:, 1]), eps, out=keep[1:])
    else:
        keep[1:] = np.abs(np.diff(points, axis=0)).max(axis=1) > eps
    return points[keep]


def smooth(points: np.ndarray, sigma: float, closed: bool = False) -> np.ndarray:
    """Gaussian-smooth a densely sampled chain; open chains keep their end points fixed.

    Removes the staircase of a pixel chain. Ends stay put because they are junction points or
    tips that other strokes meet; the smoothing fades out towards them.
    """
    points = np.asarray(points, dtype=np.float64)
    if sigma <= 0 or len(points) < 3:
        return points.copy()
    if closed:
        return gaussian_filter1d(points, sigma, axis=0, mode="wrap")
    out = gaussian_filter1d(points, sigma, axis=0, mode="nearest")
    # Blend back to the original near the ends so they do not shrink inwards.
    n = len(points)
    ramp = np.minimum(np.arange(n), np.arange(n)[::-1]) / max(2.0 * sigma, 1e-9)
    w = np.clip(ramp, 0.0, 1.0)[:, None]
    return w * out + (1.0 - w) * points


def simplify(points: np.ndarray, epsilon: float, closed: bool = False) -> np.ndarray:
    """Douglas–Peucker simplification (cv2.approxPolyDP), keeping both ends of open chains."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 3 or epsilon <= 0:
        return points.copy()
    if not closed and np.abs(points[0] - points[-1]).max() < 1e-6:
        # A loop stored open (last point = first): approxPolyDP drops the repeated end point, so
        # split at the vertex farthest from the seam and simplify the two halves as open chains.
        k = int(np.argmax(np.hypot(*(points - points[0]).T)))
        if k == 0:
            return points[:1].copy()
        return np.concatenate([simplify(points[: k + 1], epsilon), simplify(points[k:], epsilon)[1:]])
    approx = cv2.approxPolyDP(points.astype(np.float32).reshape(-1, 1, 2), float(epsilon), closed)
    out = approx.reshape(-1, 2).astype(np.float64)
    if not closed:
        # approxPolyDP keeps the first point; make the ends exact (float32 round trip), appending
        # the last one should it ever be left out rather than overwriting a kept corner.
        out[0] = points[0]
        if np.abs(out[-1] - points[-1]).max() < 1e-3:
            out[-1] = points[-1]
        else:
            out = np.concatenate([out, points[-1:]])
    return out


def resample(points: np.ndarray, spacing: float) -> np.ndarray:
    """Linear resampling at (about) uniform arc-length spacing, ends kept."""
    points = dedupe(points)
    if len(points) < 2:
        return points.copy()
    s = cumulative_length(points)
    n = max(2, int(np.ceil(s[-1] / max(spacing, 1e-6))) + 1)
    t = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(t, s, points[:, 0]), np.interp(t, s, points[:, 1])], axis=1)


def catmull_rom(points: np.ndarray, spacing: float, alpha: float = 0.5) -> np.ndarray:
    """Smooth curve through the vertices (centripetal Catmull-Rom), sampled every ~``spacing``.

    Centripetal (alpha = 0.5) parameterization avoids cusps and overshoot at sharp corners that
    the uniform variant produces, so corners of simplified outlines stay where they were.
    """
    p = dedupe(points)
    if len(p) < 3:
        return resample(p, spacing)
    # Phantom end points by reflection so the curve starts/ends at the real ends.
    ext = np.concatenate([2 * p[:1] - p[1:2], p, 2 * p[-1:] - p[-2:-1]])
    d = np.maximum(np.linalg.norm(np.diff(ext, axis=0), axis=1) ** alpha, 1e-6)
    knots = np.concatenate([[0.0], np.cumsum(d)])
    # Segment i runs from p[i] to p[i+1] (ext index i+1 → i+2); sample all segments at once.
    seg_len = np.linalg.norm(np.diff(p, axis=0), axis=1)
    counts = np.maximum(1, np.ceil(seg_len / max(spacing, 1e-6)).astype(int))
    seg = np.repeat(np.arange(len(p) - 1), counts)
    frac = (np.arange(len(seg)) - np.repeat(np.cumsum(counts) - counts, counts)) / counts[seg]
    i = seg + 1
    t0, t1, t2, t3 = (knots[i + k][:, None] for k in (-1, 0, 1, 2))
    p0, p1, p2, p3 = (ext[i + k] for k in (-1, 0, 1, 2))
    t = t1 + frac[:, None] * (t2 - t1)
    a1 = (t1 - t) / (t1 - t0) * p0 + (t - t0) / (t1 - t0) * p1
    a2 = (t2 - t) / (t2 - t1) * p1 + (t - t1) / (t2 - t1) * p2
    a3 = (t3 - t) / (t3 - t2) * p2 + (t - t2) / (t3 - t2) * p3
    b1 = (t2 - t) / (t2 - t0) * a1 + (t - t0) / (t2 - t0) * a2
    b2 = (t3 - t) / (t3 - t1) * a2 + (t - t1) / (t3 - t1) * a3
    curve = (t2 - t) / (t2 - t1) * b1 + (t - t1) / (t2 - t1) * b2
    return np.concatenate([curve, p[-1:]])


def tangents(points: np.ndarray) -> np.ndarray:
    """Unit tangents at each vertex (central differences)."""
    if len(points) < 2:
        return np.zeros_like(points)
    g = np.empty_like(points, dtype=np.float64)
    g[1:-1] = points[2:] - points[:-2]
    g[0], g[-1] = points[1] - points[0], points[-1] - points[-2]
    n = np.hypot(g[:, 0], g[:, 1])[:, None]
    return g / np.maximum(n, 1e-12)


def normals(points: np.ndarray) -> np.ndarray:
    """Unit normals (tangent rotated by +90°) at each vertex."""
    t = tangents(points)
    return np.stack([-t[:, 1], t[:, 0]], axis=1)
