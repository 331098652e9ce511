"""The paper's losses (Smirnov et al. 2021 §3.3): area-weighted Chamfer, normal alignment,
collision, patch flatness, template normals, global symmetry, and their weighted total.

Every term returns one value per batch item ``(B,)``; ``total_loss`` combines them with
``LossWeights`` (paper values; weight 0 switches a term off). The terms and their ablation
flags are one table, ``train.losses.terms.LOSS_TERMS``; their weights ``LossWeights``.
"""

from __future__ import annotations

from train.losses.chamfer import Groups, Matches, chamfer_loss, match_points, normal_alignment_loss
from train.losses.collision import collision_loss
from train.losses.regularizers import flatness_loss, symmetry_loss, template_normal_loss
from train.losses.total import TERMS, loss_terms, total_loss, weighted_sum
from train.losses.weights import LossWeights

__all__ = [
    "Groups",
    "LossWeights",
    "Matches",
    "TERMS",
    "chamfer_loss",
    "collision_loss",
    "flatness_loss",
    "loss_terms",
    "match_points",
    "normal_alignment_loss",
    "symmetry_loss",
    "template_normal_loss",
    "total_loss",
    "weighted_sum",
]
