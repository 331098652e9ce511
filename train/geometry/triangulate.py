"""Triangulation of patches over the grid of grid.py; a welded mesh for export."""

from __future__ import annotations

import functools

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from train.geometry.coons import coons_basis, points_from_basis
from train.geometry.grid import grid_params, grid_triangulation


def triangulate_patches(patches: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """Images of a k×k boundary grid: vertices ``(..., P, k*k, 3)`` (differentiable), faces ``(F, 3)``
    (shared between calls: do not modify them)."""
    return points_from_basis(patches, grid_basis(k, patches.dtype, patches.device)), grid_faces(k, patches.device)


@functools.lru_cache(maxsize=64)
def grid_basis(k: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """Coons point weights ``(k*k, 16)`` of the k×k boundary grid on ``device``: made once (the
    collision term triangulates every step at the same grid), the same numbers as ``coons_points``'
    own (computed there, on that device, from the same samples)."""
    with torch.inference_mode(False):  # a tensor kept for later steps must be usable by autograd
        return coons_basis(grid_params(k, dtype=dtype).to(device), dtype, device)[0]


@functools.lru_cache(maxsize=64)
def grid_faces(k: int, device: torch.device) -> Tensor:
    """``grid_triangulation(k)`` on ``device``, made once (shared: do not modify)."""
    with torch.inference_mode(False):
        return grid_triangulation(k).to(device)


def welded_mesh(patches: Tensor, k: int = 16, tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """One triangle mesh of all patches ``(P, 4, 4, 3)`` with coincident boundary vertices merged.

    Shared boundary curves are evaluated from the same control points, so their grid vertices
    coincide up to rounding and are welded (within ``tol``), giving a closed mesh for conforming
    templates. Each cluster keeps its lowest vertex index (deterministic); collapsed triangles
    are dropped. Returns float64 vertices ``(V, 3)`` and int64 faces ``(F, 3)``.
    """
    verts, faces = triangulate_patches(patches.detach().double().cpu(), k)
    num_p, per = verts.shape[0], verts.shape[1]
    v = verts.reshape(-1, 3).numpy()
    f = (faces.numpy()[None] + per * np.arange(num_p)[:, None, None]).reshape(-1, 3)
    parent = np.arange(len(v))
    for i, j in sorted(cKDTree(v).query_pairs(tol)):
        ri, rj = _root(parent, i), _root(parent, j)
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)
    roots = np.array([_root(parent, i) for i in range(len(v))])
    keep, remap = np.unique(roots, return_inverse=True)
    f = remap[f]
    good = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    return v[keep], f[good].astype(np.int64)


def _root(parent: np.ndarray, i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return int(i)
