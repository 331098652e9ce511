"""Patch flatness, template normals, and global symmetry (the paper's L_flat, L_template, L_sym),
and a fold term of our own."""

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


# a template sample takes part in the fold term where its normal is within about 73 degrees of its
# patch's mean normal: strongly curved corners of the template may turn further on their own
_FOLD_GATE = 0.3


def fold_loss(normals: Tensor, jacobian: Tensor, template_normals: Tensor, valid: Tensor | None = None) -> Tensor:
    """Share of a patch folded back over itself, per batch item ``(B,)``: mean over samples of
    ``relu(−n · n̄)``, where ``n̄`` is the patch's own area-weighted mean normal (held fixed), on
    the samples where the template's normal faces its own patch's mean way.

    Not in the paper. A patch that folds through itself (what the CAD kernel rejects) has a
    Jacobian that nearly vanishes along the fold and a normal turned past 90 degrees beyond it;
    the Chamfer and template-normal terms weight by |J| and hardly see the place
    (BENCHMARKS.md, "Where the CAD kernel rejects the predictions"). A fold that stays in one
    plane has no gradient here (its normal flips without turning); folds of curved patches, the
    predictions' kind, do. ``normals (B, P, S, 3)``,
    ``jacobian (B, P, S)``, ``template_normals (P, S, 3)`` at the same samples."""
    mean = (normals * jacobian[..., None]).sum(-2).detach()
    mean = mean / mean.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    turned = torch.relu(-(normals * mean.unsqueeze(-2)).sum(-1))  # (B, P, S)
    t_mean = template_normals.mean(-2)
    t_mean = t_mean / t_mean.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    gate = ((template_normals * t_mean.unsqueeze(-2)).sum(-1) > _FOLD_GATE).to(turned.dtype)  # (P, S)
    turned = turned * gate
    if valid is not None:
        turned = turned * valid.expand(turned.shape).to(turned.dtype)
    return turned.mean((-2, -1))
