"""The median model of a category w.r.t. Chamfer distance (the model minimizing the summed
distance to all others; models within a category are aligned, so it is a typical shape)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` area-uniform points on a triangle mesh, drawn from ``rng`` only."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not area.sum() > 0:
        raise ValueError("mesh has zero area")
    face = rng.choice(len(tri), size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[face]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])


def chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric Chamfer distance: mean nearest-neighbour distance a→b plus b→a (unsquared)."""
    return float(cKDTree(b).query(a)[0].mean() + cKDTree(a).query(b)[0].mean())


def chamfer_matrix(clouds: list[np.ndarray]) -> np.ndarray:
    n = len(clouds)
    d = np.zeros((n, n))
    trees = [cKDTree(c) for c in clouds]
    for i in range(n):
        for j in range(i + 1, n):
            d[i, j] = d[j, i] = trees[j].query(clouds[i])[0].mean() + trees[i].query(clouds[j])[0].mean()
    return d


def median_index(distances: np.ndarray) -> int:
    """Index of the row with the smallest sum (the lowest index on ties)."""
    sums = np.asarray(distances).sum(axis=1)
    return int(np.flatnonzero(sums == sums.min())[0])
