"""Polyline geometry: arc length, smoothing, simplification and smooth (Catmull-Rom) resampling.

Every function takes and returns float (K, 2) arrays of (u, v) points and never mutates its input.
"""

from __future__ import annotations

import cv2
import numba
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


@numba.njit(cache=True)
def _resampled(p, n0, spacing, out, o):
    """``resample`` of the deduplicated p[:n0] (< 3 points) written at out[o:]; returns the new o."""
    if n0 < 2:
        for i in range(n0):
            out[o + i] = p[i]
        return o + n0
    s = np.zeros(n0)
    for i in range(1, n0):
        s[i] = s[i - 1] + np.hypot(p[i, 0] - p[i - 1, 0], p[i, 1] - p[i - 1, 1])
    n = max(2, int(np.ceil(s[n0 - 1] / max(spacing, 1e-6))) + 1)
    step = s[n0 - 1] / (n - 1)
    for j in range(n):  # np.linspace(0, s[-1], n), then np.interp per axis
        t = j / (n - 1) * s[n0 - 1] if step == 0 else j * step + 0.0
        if j == n - 1:
            t = s[n0 - 1]
        for axis in range(2):
            out[o + j, axis] = interp_one(t, s, p[:n0, axis])
    return o + n


@numba.njit(cache=True)
def interp_one(x, xp, fp):
    """``np.interp(x, xp, fp)`` for one x and a non-decreasing xp (numpy's formula and cases)."""
    n = len(xp)
    if x > xp[n - 1]:
        return fp[n - 1]
    if x < xp[0]:
        return fp[0]
    lo, hi = 0, n  # the last j with xp[j] <= x
    while lo < hi:
        mid = (lo + hi) >> 1
        if x >= xp[mid]:
            lo = mid + 1
        else:
            hi = mid
    j = lo - 1
    if j == n - 1 or xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    r = slope * (x - xp[j]) + fp[j]
    if np.isnan(r):
        r = slope * (x - xp[j + 1]) + fp[j + 1]
        if np.isnan(r) and fp[j] == fp[j + 1]:
            r = fp[j]
    return r


@numba.njit(cache=True)
def _catmull_rom_all(points, starts, spacing):
    """``catmull_rom`` of every stroke of flat (points, starts), numpy's arithmetic step by step
    (``** 0.5`` is numpy's square root, sums run in order)."""
    n_strokes = len(starts) - 1
    spacing = max(spacing, 1e-6)
    size = 0
    for k in range(n_strokes):  # an upper bound on the output
        for i in range(starts[k] + 1, starts[k + 1]):
            d = np.hypot(points[i, 0] - points[i - 1, 0], points[i, 1] - points[i - 1, 1])
            size += max(1, int(np.ceil(d / spacing))) + 1
        size += 4
    out = np.empty((size, 2))
    out_starts = np.zeros(n_strokes + 1, np.int64)
    o = 0
    for k in range(n_strokes):
        i0, i1 = starts[k], starts[k + 1]
        p = np.empty((i1 - i0 + 2, 2))  # rows 1..m: the deduplicated stroke, 0 and m + 1: phantoms
        m = 0
        for i in range(i0, i1):
            if m == 0 or max(abs(points[i, 0] - p[m, 0]), abs(points[i, 1] - p[m, 1])) > 1e-6:
                m += 1
                p[m] = points[i]
        if m < 3:
            o = _resampled(p[1:], m, spacing, out, o)
            out_starts[k + 1] = o
            continue
        p[0, 0], p[0, 1] = 2 * p[1, 0] - p[2, 0], 2 * p[1, 1] - p[2, 1]
        p[m + 1, 0], p[m + 1, 1] = 2 * p[m, 0] - p[m - 1, 0], 2 * p[m, 1] - p[m - 1, 1]
        knots = np.zeros(m + 2)
        for i in range(m + 1):
            dx, dy = p[i + 1, 0] - p[i, 0], p[i + 1, 1] - p[i, 1]
            knots[i + 1] = knots[i] + max(np.sqrt(np.sqrt(dx * dx + dy * dy)), 1e-6)
        for i in range(1, m):  # the segment from p[i] to p[i + 1]
            dx, dy = p[i + 1, 0] - p[i, 0], p[i + 1, 1] - p[i, 1]
            count = max(1, int(np.ceil(np.sqrt(dx * dx + dy * dy) / spacing)))
            t0, t1, t2, t3 = knots[i - 1], knots[i], knots[i + 1], knots[i + 2]
            for j in range(count):
                t = t1 + j / count * (t2 - t1)
                for a in range(2):
                    p0, p1, p2, p3 = p[i - 1, a], p[i, a], p[i + 1, a], p[i + 2, a]
                    a1 = (t1 - t) / (t1 - t0) * p0 + (t - t0) / (t1 - t0) * p1
                    a2 = (t2 - t) / (t2 - t1) * p1 + (t - t1) / (t2 - t1) * p2
                    a3 = (t3 - t) / (t3 - t2) * p2 + (t - t2) / (t3 - t2) * p3
                    b1 = (t2 - t) / (t2 - t0) * a1 + (t - t0) / (t2 - t0) * a2
                    b2 = (t3 - t) / (t3 - t1) * a2 + (t - t1) / (t3 - t1) * a3
                    out[o, a] = (t2 - t) / (t2 - t1) * b1 + (t - t1) / (t2 - t1) * b2
                o += 1
        out[o] = p[m]
        o += 1
        out_starts[k + 1] = o
    return out[:o], out_starts


def catmull_rom_flat(points: np.ndarray, starts: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """``catmull_rom`` of every stroke of flat strokes (points (N, 2), starts (S + 1,)) in one
    compiled call; returns flat strokes."""
    return _catmull_rom_all(np.ascontiguousarray(points, np.float64), np.asarray(starts, np.int64), float(spacing))


def catmull_rom(points: np.ndarray, spacing: float) -> np.ndarray:
    """Smooth curve through the vertices (centripetal Catmull-Rom), sampled every ~``spacing``.

    Centripetal (alpha = 0.5) parameterization avoids cusps and overshoot at sharp corners that
    the uniform variant produces, so corners of simplified outlines stay where they were. Fewer
    than three distinct vertices: ``resample``.
    """
    p = np.asarray(points, np.float64).reshape(-1, 2)
    return catmull_rom_flat(p, np.array([0, len(p)]), spacing)[0]


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
