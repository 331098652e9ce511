"""Patch flatness, template normals, and global symmetry (the paper's L_flat, L_template, L_sym)."""

from __future__ import annotations

import torch
from torch import Tensor


def _weighted_mean(values: Tensor, jacobian: Tensor, valid: Tensor | None) -> Tensor:
    w = jacobian if valid is None else jacobian * valid.expand(jacobian.shape).to(jacobian.dtype)
    dims = tuple(range(1, w.dim()))
    return (values * w).sum(dims) / w.sum(dims).clamp_min(1e-12)


def flatness_loss(points: Tensor, st: Tensor, jacobian: Tensor, valid: Tensor | None = None) -> Tensor:
    """Area-weighted squared residual of a least-squares affine fit P ≈ A(s,t) + b per patch.

    ``points (B, P, S, 3)`` at ``st (S, 2)`` or ``(P, S, 2)``; ``jacobian (B, P, S)`` → ``(B,)``.
    """
    st = st.to(points.dtype)
    design = torch.cat([st, torch.ones_like(st[..., :1])], dim=-1)  # (…, S, 3)
    xtx = design.transpose(-1, -2) @ design  # (…, 3, 3)
    xtp = design.transpose(-1, -2) @ points  # (B, P, 3, 3)
    # solve_ex: the same solve without its error check, which on a GPU reads a flag back every
    # call (the normal matrix of distinct samples is never singular)
    coef = torch.linalg.solve_ex(xtx.expand(xtp.shape[:-2] + (3, 3)), xtp)[0]
    resid = ((design @ coef - points) ** 2).sum(-1)
    return _weighted_mean(resid, jacobian, valid)


def template_normal_loss(
    normals: Tensor, template_normals: Tensor, jacobian: Tensor, valid: Tensor | None = None
) -> Tensor:
    """Area-weighted ‖n_P − n_T‖² with template normals at the same (s, t): ``(P, S, 3)`` or
    ``(B, P, S, 3)`` → ``(B,)``."""
    return _weighted_mean(((normals - template_normals) ** 2).sum(-1), jacobian, valid)


def symmetry_loss(points: Tensor, pairs: Tensor, plane_x: float = 0.0, valid: Tensor | None = None) -> Tensor:
    """Mean over pairs (i, j) of ‖(x_i − a, y_i, z_i) − (a − x_j, y_j, z_j)‖², a = plane_x.

    ``points (B, N, 3)`` (all template control points), ``pairs (K, 2)``; a pair (k, k) pins a
    point to the plane. ``valid (B, K)`` leaves out pairs (points of absent parts). No pairs → zeros.
    """
    if pairs.numel() == 0:
        return points.new_zeros(points.shape[0])
    pairs = pairs.to(points.device)
    pi, pj = points[:, pairs[:, 0]], points[:, pairs[:, 1]]
    # (x_i − a) − (a − x_j) = x_i + x_j − 2a ; y_i − y_j ; z_i − z_j
    diff = torch.stack([pi[..., 0] + pj[..., 0] - 2 * plane_x, pi[..., 1] - pj[..., 1], pi[..., 2] - pj[..., 2]], -1)
    sq = (diff**2).sum(-1)
    if valid is None:
        return sq.mean(-1)
    w = valid.to(sq.dtype)
    return (sq * w).sum(-1) / w.sum(-1).clamp_min(1.0)
