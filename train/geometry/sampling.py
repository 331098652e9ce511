"""Parameter-domain sampling: random (s, t) from an explicit torch.Generator (regular grids: grid.py) and
area-uniform surface samples (for metrics)."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from train.geometry.coons import evaluate_patches
from train.geometry.grid import grid_params, grid_triangulation


def samples_per_patch(num_points: int, num_patches: int) -> int:
    """k² samples per patch with k = ceil(sqrt(num_points / num_patches)) (the authors' rule)."""
    k = math.ceil(math.sqrt(num_points / max(num_patches, 1)))
    return k * k


def uniform_params(
    num_patches: int,
    num_samples: int,
    generator: torch.Generator,
    device: torch.device | str = "cpu",
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Independent uniform (s, t) per patch → ``(P, S, 2)``. Draws only from ``generator``."""
    st = torch.rand((num_patches, num_samples, 2), generator=generator, dtype=torch.float64)
    return st.to(device=device, dtype=dtype)


def sample_surface_uniform(
    patches: Tensor, num_points: int, generator: torch.Generator, grid: int = 16
) -> tuple[Tensor, Tensor]:
    """Area-uniform points and unit normals on the union of patches.

    ``patches (..., P, 4, 4, 3)`` → points, normals ``(..., num_points, 3)``. Triangles of a
    ``grid``×``grid`` triangulation are chosen by area, a point inside is drawn in (s, t) and the
    exact Coons point/normal is evaluated there (so points lie on the surface, not on the mesh).
    Not differentiable with respect to the choice of samples; it is for evaluation.
    """
    lead = patches.shape[:-4]
    flat = patches.reshape(-1, *patches.shape[-4:])
    st_grid = grid_params(grid, dtype=patches.dtype).to(patches.device)
    faces = grid_triangulation(grid).to(patches.device)
    out_p, out_n = [], []
    for item in flat:
        with torch.no_grad():
            verts = evaluate_patches(item, st_grid).points  # (P, V, 3)
            tri = verts[:, faces]  # (P, F, 3, 3)
            area = 0.5 * torch.linalg.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]).norm(
                dim=-1
            )
            weights = area.reshape(-1).double().cpu()
            choice = torch.multinomial(weights, num_points, replacement=True, generator=generator)
            uv = torch.rand((num_points, 2), generator=generator, dtype=torch.float64)
        flip = uv.sum(-1) > 1  # fold the unit square onto the triangle
        uv[flip] = 1.0 - uv[flip]
        n_faces = faces.shape[0]
        patch_id = (choice // n_faces).to(patches.device)
        face = faces[(choice % n_faces).to(patches.device)]  # (N, 3)
        corner = st_grid[face].double()  # (N, 3, 2)
        uv = uv.to(patches.device)
        st = corner[:, 0] + uv[:, :1] * (corner[:, 1] - corner[:, 0]) + uv[:, 1:] * (corner[:, 2] - corner[:, 0])
        # one "patch" per sample, each evaluated at its own single (s, t)
        ev = evaluate_patches(item[patch_id], st[:, None, :].to(patches.dtype))
        out_p.append(ev.points[:, 0])
        out_n.append(ev.normals[:, 0])
    points = torch.stack(out_p).reshape(*lead, num_points, 3)
    normals = torch.stack(out_n).reshape(*lead, num_points, 3)
    return points, normals
