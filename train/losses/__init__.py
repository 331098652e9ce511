"""The paper's losses (Smirnov et al. 2021 §3.3): area-weighted Chamfer, normal alignment,
collision, patch flatness, template normals, global symmetry, and their weighted total.

Every term returns one value per batch item ``(B,)``; ``total_loss`` combines them with
``LossWeights`` (paper values; weight 0 switches a term off). The terms, their default weights
and ablation flags are one table, ``train.losses.terms.LOSS_TERMS``.

The names below are loaded on first use, so that importing ``train.losses.terms`` (to register a
term) does not build ``LossWeights`` before the table is complete.
"""

from __future__ import annotations

import importlib

_WHERE = {
    "Groups": "chamfer", "Matches": "chamfer", "chamfer_loss": "chamfer", "match_points": "chamfer",
    "normal_alignment_loss": "chamfer",
    "collision_loss": "collision",
    "flatness_loss": "regularizers", "symmetry_loss": "regularizers", "template_normal_loss": "regularizers",
    "TERMS": "total", "loss_terms": "total", "total_loss": "total", "weighted_sum": "total",
    "LossWeights": "weights",
}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'train.losses' has no attribute {name!r}")
    return getattr(importlib.import_module(f"train.losses.{_WHERE[name]}"), name)
