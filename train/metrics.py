"""Evaluation metrics for predicted patches against target surface samples.

Two Chamfer conventions, stated exactly:
- ``chamfer_loss_style``: the training loss L_Ch — unsquared Euclidean distances; patch side
  Jacobian-weighted over random (s, t), target side a plain mean; the two directions summed.
- ``chamfer_l2_x1000``: what AtlasNet / Pixel2Mesh-style tables report — squared Euclidean
  distances between area-uniform point sets, mean over each set, the two directed means summed
  (``average_directions=True`` halves it), times 1000.
F-score at a distance threshold (0.01 / 0.02 on unit-radius models) and normal consistency
(mean |cos| between each point's normal and its nearest neighbour's, averaged over both
directions; unoriented). Intersecting patch pairs: ``train.geometry.intersections``.
``relative_change_interval``: a network's mean against a baseline's, with a bootstrap interval over
the shapes measured.
"""

from __future__ import annotations

import torch
from torch import Tensor

from train.geometry.coons import evaluate_patches
from train.geometry.sampling import samples_per_patch, uniform_params
from train.losses.chamfer import chamfer_loss
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
def normal_consistency(
    pred_points: Tensor, pred_normals: Tensor, target_points: Tensor, target_normals: Tensor
) -> Tensor:
    """Mean |n_x · n_NN(x)| over both directions, averaged → ``(B,)`` in [0, 1] (unit normals)."""
    a = (pred_normals * gather_points(target_normals, nearest_indices(pred_points, target_points))).sum(-1).abs()
    b = (target_normals * gather_points(pred_normals, nearest_indices(target_points, pred_points))).sum(-1).abs()
    return 0.5 * (a.mean(-1) + b.mean(-1))


def relative_change_interval(
    values: Tensor, baseline: Tensor, resamples: int = 2000, level: float = 0.95, seed: int = 0
) -> dict[str, float]:
    """``mean(values) / mean(baseline) - 1`` over paired per-shape measures ``(N,)``, with a
    percentile bootstrap interval over the shapes (the same resample for both, seeded): how far
    the figure moves with which ~100 shapes a test split holds, a point or more on 100 shapes."""
    if values.shape != baseline.shape or values.ndim != 1 or len(values) == 0:
        raise ValueError(f"need two equal (N,) measures, got {tuple(values.shape)} and {tuple(baseline.shape)}")
    v, b = values.double(), baseline.double()
    gen = torch.Generator().manual_seed(seed)
    changes = []
    for start in range(0, resamples, 100):  # 100 resamples at a time: memory stays ~100 x N for a large split
        picks = torch.randint(len(v), (min(100, resamples - start), len(v)), generator=gen)
        changes.append(v[picks].mean(1) / b[picks].mean(1) - 1)
    changes = torch.cat(changes)
    tail = (1 - level) / 2
    low, high = torch.quantile(changes, torch.tensor([tail, 1 - tail], dtype=changes.dtype)).tolist()
    return {"change": float(v.mean() / b.mean() - 1), "low": low, "high": high, "level": level}
