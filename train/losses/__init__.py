"""The paper's losses (Smirnov et al. 2021 §3.3): area-weighted Chamfer, normal alignment,
collision, patch flatness, template normals, global symmetry, and their weighted total.

Every term returns one value per batch item ``(B,)``; ``total_loss`` combines them with
``LossWeights`` (paper values; weight 0 switches a term off).
"""

from train.losses.chamfer import Groups, Matches, chamfer_loss, match_points, normal_alignment_loss
from train.losses.collision import (
    CollisionPairs,
    collision_loss,
    collision_pairs,
    unconnected_pairs,
)
from train.losses.regularizers import flatness_loss, symmetry_loss, template_normal_loss
from train.losses.total import TERMS, loss_terms, total_loss, weighted_sum
from train.losses.weights import LossWeights

__all__ = [
    "TERMS",
    "CollisionPairs",
    "Groups",
    "LossWeights",
    "Matches",
    "chamfer_loss",
    "collision_loss",
    "collision_pairs",
    "flatness_loss",
    "loss_terms",
    "match_points",
    "normal_alignment_loss",
    "symmetry_loss",
    "template_normal_loss",
    "total_loss",
    "unconnected_pairs",
    "weighted_sum",
]
