"""Nearest neighbours without a dense N×M matrix on CPU, with differentiable distances.

The search runs on detached coordinates: on CPU, 3-D points go to the exact hashed-grid search
of ``train.grid_nn`` (1.5-2.6x cheaper than a k-d tree per batch item on training's point
clouds, BENCHMARKS.md), other dimensions (normal-aware matching searches in 6-D) to scipy's cKDTree per batch
item; on a GPU (any device but the CPU), chunked torch.cdist on that device, which reads
nothing back to the host. Distances are then recomputed in torch from the gathered
neighbours so gradients flow to both point sets.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from train.grid_nn import grid_nearest


def nearest_indices(query: Tensor, reference: Tensor, chunk: int = 4096) -> Tensor:
    """Index of the nearest ``reference`` point for each ``query`` point.

    ``query (B, N, D)``, ``reference (B, M, D)`` → ``(B, N)`` int64 on the query's device. Ties
    (equal distances, e.g. coincident reference points) go to the lowest index on the 3-D CPU
    path; elsewhere to whichever the k-d tree or argmin picks.
    """
    q, r = query.detach(), reference.detach()
    if q.device.type != "cpu":  # on the tensors' own device: no copy to the host and back
        return device_nearest(q, r, chunk)
    qn = q.double().cpu().numpy()
    rn = r.double().cpu().numpy()
    idx = grid_nearest(qn, rn) if qn.shape[-1] == 3 else None
    if idx is not None:
        return torch.from_numpy(idx).to(query.device)
    return torch.from_numpy(kdtree_nearest(qn, rn)).to(query.device)


def device_nearest(query: Tensor, reference: Tensor, chunk: int = 4096) -> Tensor:
    """``nearest_indices`` in torch alone (chunked ``cdist`` + ``argmin``), on any device: the GPU
    path (queries per chunk, so the distance matrix stays ``chunk`` × M per item)."""
    out = [torch.cdist(query[:, s : s + chunk], reference).argmin(dim=-1) for s in range(0, query.shape[1], chunk)]
    return torch.cat(out, dim=1)


def kdtree_nearest(query: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """One scipy cKDTree build + query per batch item: any dimension (``(B, N, D)``, ``(B, M, D)``
    → ``(B, N)``); the CPU path for D ≠ 3 and the reference the grid is measured against."""
    idx = np.empty(query.shape[:2], dtype=np.int64)
    for b in range(query.shape[0]):
        idx[b] = cKDTree(reference[b]).query(query[b], k=1, workers=1)[1]
    return idx


def gather_points(points: Tensor, idx: Tensor) -> Tensor:
    """``points (B, M, C)`` at ``idx (B, N)`` → ``(B, N, C)``."""
    return torch.gather(points, 1, idx[..., None].expand(*idx.shape, points.shape[-1]))


def nearest_distances(query: Tensor, reference: Tensor, squared: bool = False) -> tuple[Tensor, Tensor]:
    """Distance from each query point to its nearest reference point, differentiable.

    Returns ``(dist (B, N), idx (B, N))``; ``squared`` gives squared Euclidean distances. The
    unsquared distance uses sqrt of a clamped square (gradient 0, not NaN, at coincident points).
    """
    idx = nearest_indices(query, reference)
    sq = ((query - gather_points(reference, idx)) ** 2).sum(-1)
    return (sq if squared else torch.sqrt(sq.clamp_min(1e-24))), idx
