"""Small constructors: straight cubic curves and bilinear patches from four corners."""

from __future__ import annotations

import torch
from torch import Tensor


def line_curve(a: Tensor, b: Tensor) -> Tensor:
    """Cubic control points of the segment a→b (interior points at 1/3, 2/3) → ``(..., 4, 3)``."""
    return torch.stack([a, (2 * a + b) / 3, (a + 2 * b) / 3, b], dim=-2)


def patch_from_corners(corners: Tensor) -> Tensor:
    """Bilinear Coons patch from corners ``(..., 4, 3)`` ordered P00, P10, P11, P01 → ``(..., 4, 4, 3)``."""
    p00, p10, p11, p01 = corners.unbind(-2)
    return torch.stack([line_curve(p00, p10), line_curve(p10, p11), line_curve(p11, p01), line_curve(p01, p00)], dim=-3)
