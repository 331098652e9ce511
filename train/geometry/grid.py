"""The regular k×k (s, t) grid of a patch and its triangulation, shared by sampling and meshing."""

from __future__ import annotations

import torch
from torch import Tensor


def grid_params(k: int, include_boundary: bool = True, dtype: torch.dtype = torch.float32) -> Tensor:
    """A k×k grid of (s, t), row-major with t as the row: index = i_t * k + i_s → ``(k*k, 2)``.

    ``include_boundary`` puts samples on the patch edges (linspace 0..1, needs k ≥ 2); otherwise
    cell centres (i + 0.5) / k.
    """
    if include_boundary:
        if k < 2:
            raise ValueError("a boundary grid needs k >= 2")
        axis = torch.linspace(0.0, 1.0, k, dtype=torch.float64)
    else:
        axis = (torch.arange(k, dtype=torch.float64) + 0.5) / k
    t, s = torch.meshgrid(axis, axis, indexing="ij")
    return torch.stack([s.reshape(-1), t.reshape(-1)], dim=-1).to(dtype)


def grid_triangulation(k: int) -> Tensor:
    """Faces ``(2(k−1)², 3)`` over the vertices of ``grid_params(k)`` (index = i_t*k + i_s).

    Counter-clockwise in (s, t), so a triangle's normal points along P_s × P_t.
    """
    i_t, i_s = torch.meshgrid(torch.arange(k - 1), torch.arange(k - 1), indexing="ij")
    a = (i_t * k + i_s).reshape(-1)
    b, c, d = a + 1, a + k + 1, a + k
    return torch.cat([torch.stack([a, b, c], -1), torch.stack([a, c, d], -1)], 0).to(torch.int64)
