"""Coons patches from four cubic boundary curves (the paper's formula), with closed-form
partial derivatives, Jacobian magnitude |P_s × P_t| and unit normals.

P(s,t) = (1−t)c1(s) + t c3(1−s) + s c2(t) + (1−s) c4(1−t)
         − [c1(0)(1−s)(1−t) + c1(1)s(1−t) + c3(1)(1−s)t + c3(0)st]
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from train.geometry.bezier import bezier_derivative, bezier_eval


class PatchSamples(NamedTuple):
    points: Tensor  # (..., P, S, 3)
    normals: Tensor  # (..., P, S, 3) unit, P_s × P_t direction
    jacobian: Tensor  # (..., P, S) |P_s × P_t|


def _split(patches: Tensor, st: Tensor) -> tuple[Tensor, ...]:
    st = st.to(patches.dtype)
    s, t = st[..., 0], st[..., 1]
    c1, c2, c3, c4 = (patches[..., k, :, :] for k in range(4))  # each (..., P, 4, 3)
    return s, t, c1, c2, c3, c4


def _corners(c1: Tensor, c3: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    # (..., P, 1, 3) so they broadcast over the sample axis
    return c1[..., 0:1, :], c1[..., 3:4, :], c3[..., 3:4, :], c3[..., 0:1, :]


def _points_formula(patches: Tensor, st: Tensor) -> Tensor:
    """The Coons formula, term by term (``coons_basis`` applies it to unit control points)."""
    s, t, c1, c2, c3, c4 = _split(patches, st)
    p00, p10, p01, p11 = _corners(c1, c3)
    S, T = s[..., None], t[..., None]
    ruled = (
        (1 - T) * bezier_eval(c1, s)
        + T * bezier_eval(c3, 1 - s)
        + S * bezier_eval(c2, t)
        + (1 - S) * bezier_eval(c4, 1 - t)
    )
    bilinear = p00 * (1 - S) * (1 - T) + p10 * S * (1 - T) + p01 * (1 - S) * T + p11 * S * T
    return ruled - bilinear


def _partials_formula(patches: Tensor, st: Tensor) -> tuple[Tensor, Tensor]:
    """Closed-form ∂P/∂s and ∂P/∂t, term by term."""
    s, t, c1, c2, c3, c4 = _split(patches, st)
    p00, p10, p01, p11 = _corners(c1, c3)
    S, T = s[..., None], t[..., None]
    p_s = (
        (1 - T) * bezier_derivative(c1, s)
        - T * bezier_derivative(c3, 1 - s)
        + bezier_eval(c2, t)
        - bezier_eval(c4, 1 - t)
        - (-(p00 * (1 - T)) + p10 * (1 - T) - p01 * T + p11 * T)
    )
    p_t = (
        -bezier_eval(c1, s)
        + bezier_eval(c3, 1 - s)
        + S * bezier_derivative(c2, t)
        - (1 - S) * bezier_derivative(c4, 1 - t)
        - (-(p00 * (1 - S)) - p10 * S + p01 * (1 - S) + p11 * S)
    )
    return p_s, p_t


def coons_basis(st: Tensor, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None) -> Tensor:
    """Weights of a patch's 16 control points (4 curves × 4, in ``patches``' order) giving its
    point, ∂P/∂s and ∂P/∂t at ``st (S, 2)`` or ``(P, S, 2)`` → ``(3, S, 16)`` or ``(3, P, S, 16)``.

    A Coons patch is linear in its control points, so the formula applied to the 16 unit control
    points gives these weights, and evaluating any batch of patches is then one matrix product
    (``evaluate_patches``): far fewer, larger operations than the formula term by term, forward
    and backward."""
    unit = torch.eye(16, dtype=dtype, device=device).reshape(16, 1, 4, 4, 1)
    st = st.to(device=device)
    rows = [_points_formula(unit, st)[..., 0], *(d[..., 0] for d in _partials_formula(unit, st))]  # (16, 1|P, S)
    w = torch.stack(rows).movedim(1, -1)  # (3, 1|P, S, 16)
    return w[:, 0] if st.dim() == 2 else w


def _apply(patches: Tensor, basis: Tensor) -> Tensor:
    """``basis (..., S, 16)`` applied to ``patches (..., P, 4, 4, 3)`` → ``(..., P, S, 3)``."""
    # einsum folds the batch into one matrix product (the broadcast ``@`` makes one per patch)
    return torch.einsum("...sk,...kd->...sd", basis, patches.flatten(-3, -2))


def coons_points(patches: Tensor, st: Tensor) -> Tensor:
    """Surface points of ``patches (..., P, 4, 4, 3)`` at ``st (S, 2)`` or ``(P, S, 2)`` → ``(..., P, S, 3)``."""
    return points_from_basis(patches, coons_basis(st, patches.dtype, patches.device)[0])


def points_from_basis(patches: Tensor, basis: Tensor) -> Tensor:
    """``coons_points`` with the point weights ``coons_basis(st)[0]`` given (samples that never
    change, such as a fixed grid, need their weights computed only once)."""
    return _apply(patches, basis)


def coons_partials(patches: Tensor, st: Tensor) -> tuple[Tensor, Tensor]:
    """Closed-form ∂P/∂s and ∂P/∂t, each ``(..., P, S, 3)``."""
    w = coons_basis(st, patches.dtype, patches.device)
    return _apply(patches, w[1]), _apply(patches, w[2])


def _safe_norm(v: Tensor, eps: float) -> Tensor:
    # sqrt of a clamped square keeps gradients finite on degenerate (zero-area) samples
    return torch.sqrt((v * v).sum(-1).clamp_min(eps * eps))


def coons_jacobian(patches: Tensor, st: Tensor, eps: float = 1e-12) -> Tensor:
    """Area element |P_s × P_t| → ``(..., P, S)``."""
    p_s, p_t = coons_partials(patches, st)
    return _safe_norm(torch.linalg.cross(p_s, p_t, dim=-1), eps)


def coons_normals(patches: Tensor, st: Tensor, eps: float = 1e-12) -> Tensor:
    """Unit normals (P_s × P_t)/|P_s × P_t| → ``(..., P, S, 3)``."""
    return evaluate_patches(patches, st, eps).normals


def evaluate_patches(patches: Tensor, st: Tensor, eps: float = 1e-12) -> PatchSamples:
    """Points, unit normals and Jacobian magnitude in one pass."""
    w = coons_basis(st, patches.dtype, patches.device)  # (3, ..., S, 16)
    s = w.shape[-2]
    # one product for points and both partials: the three weight blocks stacked along samples
    both = _apply(patches, torch.cat(w.unbind(0), dim=-2))  # (..., P, 3S, 3)
    points, p_s, p_t = both[..., :s, :], both[..., s : 2 * s, :], both[..., 2 * s :, :]
    cross = torch.linalg.cross(p_s, p_t, dim=-1)
    jac = _safe_norm(cross, eps)
    return PatchSamples(points, cross / jac[..., None], jac)
