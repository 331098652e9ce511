"""Exact count of intersecting patch pairs of one shape (the paper's self-intersection figure).

Independent of the collision loss: triangle against triangle (an edge of one crossing the other,
Möller–Trumbore), both ways, on the same truncated grid triangulation.
"""

from __future__ import annotations

import numpy as np
from torch import Tensor

from train.geometry.triangulate import triangulate_patches
from train.losses.collision import CollisionPairs, unconnected_pairs


def _segments_hit_triangles(p0: np.ndarray, p1: np.ndarray, tri: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Möller–Trumbore: does segment p0→p1 cross triangle ``tri (..., 3, 3)``? → bool (...)."""
    d = p1 - p0
    e1, e2 = tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]
    h = np.cross(d, e2)
    a = (e1 * h).sum(-1)
    ok = np.abs(a) > eps
    f = np.where(ok, 1.0 / np.where(ok, a, 1.0), 0.0)
    s = p0 - tri[..., 0, :]
    u = f * (s * h).sum(-1)
    q = np.cross(s, e1)
    v = f * (d * q).sum(-1)
    t = f * (e2 * q).sum(-1)
    return ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)


def triangles_intersect(ta: np.ndarray, tb: np.ndarray) -> np.ndarray:
    """Pairwise test of triangles ``ta (N, 3, 3)`` with ``tb (N, 3, 3)`` → bool ``(N,)``.

    Two non-coplanar triangles intersect iff an edge of one crosses the other; coplanar overlaps
    (measure zero for fitted patches) are not reported.
    """
    hit = np.zeros(len(ta), dtype=bool)
    for x, y in ((ta, tb), (tb, ta)):
        for e in range(3):
            hit |= _segments_hit_triangles(x[:, e], x[:, (e + 1) % 3], y)
    return hit


def count_intersecting_pairs(patches: Tensor, pairs: CollisionPairs | None = None, present: Tensor | None = None) -> int:
    """Number of patch pairs whose (truncated) triangulations intersect, for one shape
    ``patches (P, 4, 4, 3)``. ``pairs`` from ``collision_pairs(template)`` truncates pairs that
    share a boundary; by default every pair is tested in full. ``present (P,)`` bool leaves out
    patches of absent parts. Boxes cull patch pairs and triangle pairs before the exact test."""
    pairs = pairs or unconnected_pairs(patches.shape[-4])
    on = None if present is None else present.cpu().numpy()
    verts, faces = triangulate_patches(patches.detach().double().cpu(), pairs.grid)
    tris = verts.numpy()[:, faces.numpy()]  # (P, F, 3, 3)
    f_np = faces.numpy()
    lo, hi = tris.min(axis=2), tris.max(axis=2)  # (P, F, 3)
    plo, phi = lo.min(axis=1), hi.max(axis=1)
    count = 0
    for k, (i, j) in enumerate(pairs.pairs.tolist()):
        if (on is not None and not (on[i] and on[j])) or np.any(plo[i] > phi[j]) or np.any(plo[j] > phi[i]):
            continue
        ki = pairs.keep_i[k].numpy()[f_np].all(-1)
        kj = pairs.keep_j[k].numpy()[f_np].all(-1)
        fi, fj = np.nonzero(ki)[0], np.nonzero(kj)[0]
        overlap = np.all(lo[i][fi][:, None] <= hi[j][fj][None], -1) & np.all(lo[j][fj][None] <= hi[i][fi][:, None], -1)
        a, b = np.nonzero(overlap)
        if len(a) and triangles_intersect(tris[i][fi[a]], tris[j][fj[b]]).any():
            count += 1
    return count
