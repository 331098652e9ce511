"""Evaluation metrics for predicted patches against target surface samples.

Two Chamfer conventions, stated exactly:
- ``chamfer_loss_style``: the training loss L_Ch — unsquared Euclidean distances; patch side
  Jacobian-weighted over random (s, t), target side a plain mean; the two directions summed.
- ``chamfer_l2_x1000``: what AtlasNet / Pixel2Mesh-style tables report — squared Euclidean
  distances between area-uniform point sets, mean over each set, the two directed means summed
  (``average_directions=True`` halves it), times 1000.
F-score at a distance threshold (0.01 / 0.02 on unit-radius models), normal consistency
(mean |cos| between each point's normal and its nearest neighbour's, averaged over both
directions; unoriented), and the number of intersecting patch pairs.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from train.geometry.coons import evaluate_patches
from train.geometry.sampling import samples_per_patch, uniform_params
from train.geometry.triangulate import triangulate_patches
from train.losses.chamfer import chamfer_loss
from train.losses.collision import CollisionPairs, unconnected_pairs
from train.nn_search import gather_points, nearest_distances, nearest_indices


@torch.no_grad()
def chamfer_loss_style(
    patches: Tensor, target_points: Tensor, generator: torch.Generator, num_points: int = 7000
) -> Tensor:
    """L_Ch as trained (unsquared, Jacobian-weighted patch side) → ``(B,)``."""
    k2 = samples_per_patch(num_points, patches.shape[-4])
    st = uniform_params(patches.shape[-4], k2, generator, patches.device, patches.dtype)
    ev = evaluate_patches(patches, st)
    return chamfer_loss(ev.points, ev.jacobian, target_points)


@torch.no_grad()
def chamfer_l2_x1000(pred_points: Tensor, target_points: Tensor, average_directions: bool = False) -> Tensor:
    """1000 × (mean_x min_y ‖x−y‖² + mean_y min_x ‖x−y‖²) per batch item ``(B,)``."""
    d_pt, _ = nearest_distances(pred_points, target_points, squared=True)
    d_tp, _ = nearest_distances(target_points, pred_points, squared=True)
    total = d_pt.mean(-1) + d_tp.mean(-1)
    return 1000.0 * (total / 2 if average_directions else total)


@torch.no_grad()
def fscore(pred_points: Tensor, target_points: Tensor, threshold: float = 0.01) -> Tensor:
    """F-score at ``threshold`` (unsquared distance): 2PR/(P+R) with precision = share of predicted
    points within the threshold of the target, recall = share of target points within it of
    the prediction → ``(B,)`` (0 where both are 0)."""
    d_pt, _ = nearest_distances(pred_points, target_points)
    d_tp, _ = nearest_distances(target_points, pred_points)
    precision = (d_pt <= threshold).double().mean(-1)
    recall = (d_tp <= threshold).double().mean(-1)
    f = 2 * precision * recall / (precision + recall).clamp_min(1e-12)
    return f.to(pred_points.dtype)


@torch.no_grad()
def normal_consistency(pred_points: Tensor, pred_normals: Tensor, target_points: Tensor, target_normals: Tensor) -> Tensor:
    """Mean |n_x · n_NN(x)| over both directions, averaged → ``(B,)`` in [0, 1] (unit normals)."""
    a = (pred_normals * gather_points(target_normals, nearest_indices(pred_points, target_points))).sum(-1).abs()
    b = (target_normals * gather_points(pred_normals, nearest_indices(target_points, pred_points))).sum(-1).abs()
    return 0.5 * (a.mean(-1) + b.mean(-1))


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


def count_intersecting_pairs(patches: Tensor, pairs: CollisionPairs | None = None) -> int:
    """Number of patch pairs whose (truncated) triangulations intersect, for one shape
    ``patches (P, 4, 4, 3)``. ``pairs`` from ``collision_pairs(template)`` truncates pairs that
    share a boundary; by default every pair is tested in full. Boxes cull patch pairs and
    triangle pairs before the exact test."""
    pairs = pairs or unconnected_pairs(patches.shape[-4])
    verts, faces = triangulate_patches(patches.detach().double().cpu(), pairs.grid)
    tris = verts.numpy()[:, faces.numpy()]  # (P, F, 3, 3)
    f_np = faces.numpy()
    lo, hi = tris.min(axis=2), tris.max(axis=2)  # (P, F, 3)
    plo, phi = lo.min(axis=1), hi.max(axis=1)
    count = 0
    for k, (i, j) in enumerate(pairs.pairs.tolist()):
        if np.any(plo[i] > phi[j]) or np.any(plo[j] > phi[i]):
            continue
        ki = pairs.keep_i[k].numpy()[f_np].all(-1)
        kj = pairs.keep_j[k].numpy()[f_np].all(-1)
        fi, fj = np.nonzero(ki)[0], np.nonzero(kj)[0]
        overlap = np.all(lo[i][fi][:, None] <= hi[j][fj][None], -1) & np.all(lo[j][fj][None] <= hi[i][fi][:, None], -1)
        a, b = np.nonzero(overlap)
        if len(a) and triangles_intersect(tris[i][fi[a]], tris[j][fj[b]]).any():
            count += 1
    return count
