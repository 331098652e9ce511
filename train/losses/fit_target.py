"""The fit term: predicted control points against the fit stage's (``--fit-patches``) per model.

Not in the paper: a build that fitted the template to each model gives the network a direct
target in its own parameter space, easier to follow early on than the Chamfer distance."""

from __future__ import annotations

from torch import Tensor


def fit_target_loss(control_points: Tensor, fit_points: Tensor, point_weight: Tensor) -> Tensor:
    """Mean squared distance per batch item ``(B,)`` between predicted ``control_points (B, N, 3)``
    and fitted ``fit_points (B, N, 3)``, over the points ``point_weight (B, N)`` counts (1: a
    control point of a present patch of an item with a fit target; 0 elsewhere). An item with
    no point counted contributes 0."""
    sq = (control_points - fit_points.to(control_points.dtype)).square().sum(-1)  # (B, N)
    w = point_weight.to(sq.dtype)
    return (sq * w).sum(-1) / w.sum(-1).clamp_min(1.0)
