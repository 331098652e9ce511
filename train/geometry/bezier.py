"""Cubic Bézier curves, batched: evaluation, derivative, and exact restriction to [a, b].

Control points are ``(..., 4, D)``. Curve parameters ``t`` are any shape that broadcasts against
the batch dims once a trailing sample axis is added (``(S,)`` for shared samples).
"""

from __future__ import annotations

import torch
from torch import Tensor


def bernstein(t: Tensor) -> Tensor:
    """Cubic Bernstein basis, ``t (...)`` → ``(..., 4)``."""
    u = 1.0 - t
    return torch.stack([u * u * u, 3.0 * t * u * u, 3.0 * t * t * u, t * t * t], dim=-1)


def bernstein_derivative(t: Tensor) -> Tensor:
    """d/dt of the cubic Bernstein basis, ``(...)`` → ``(..., 4)``."""
    u = 1.0 - t
    return torch.stack([-3.0 * u * u, 3.0 * u * u - 6.0 * t * u, 6.0 * t * u - 3.0 * t * t, 3.0 * t * t], dim=-1)


def _apply_basis(ctrl: Tensor, basis: Tensor) -> Tensor:
    # ctrl (..., 4, D) with basis (..., S, 4): add a sample axis to ctrl and contract over the 4.
    return (basis.unsqueeze(-1) * ctrl.unsqueeze(-3)).sum(dim=-2)


def bezier_eval(ctrl: Tensor, t: Tensor) -> Tensor:
    """Points of curves ``ctrl (..., 4, D)`` at parameters ``t (..., S)`` → ``(..., S, D)``."""
    return _apply_basis(ctrl, bernstein(t.to(ctrl.dtype)))


def bezier_derivative(ctrl: Tensor, t: Tensor) -> Tensor:
    """Tangent dc/dt of curves ``ctrl (..., 4, D)`` at ``t (..., S)`` → ``(..., S, D)``."""
    return _apply_basis(ctrl, bernstein_derivative(t.to(ctrl.dtype)))


def blossom(ctrl: Tensor, u1: Tensor, u2: Tensor, u3: Tensor) -> Tensor:
    """Polar form f(u1, u2, u3) of cubic curves ``(..., 4, D)``; ``u*`` broadcast to ``(...)``.

    de Casteljau with a different parameter at each level; symmetric in its arguments and equal
    to the curve at f(t, t, t).
    """
    p = ctrl
    for u in (u1, u2, u3):
        u = torch.as_tensor(u, dtype=ctrl.dtype, device=ctrl.device)[..., None, None]
        p = (1.0 - u) * p[..., :-1, :] + u * p[..., 1:, :]
    return p[..., 0, :]


def bezier_subdivide(ctrl: Tensor, a: Tensor | float, b: Tensor | float) -> Tensor:
    """Control points of the same curve restricted to [a, b] (reparameterized to [0, 1]).

    Exact (blossoming): the result traces exactly the parent's points between c(a) and c(b);
    a > b gives the reversed piece. ``a``, ``b`` broadcast to the batch dims of ``ctrl``.
    """
    a = torch.as_tensor(a, dtype=ctrl.dtype, device=ctrl.device)
    b = torch.as_tensor(b, dtype=ctrl.dtype, device=ctrl.device)
    return torch.stack(
        [blossom(ctrl, a, a, a), blossom(ctrl, a, a, b), blossom(ctrl, a, b, b), blossom(ctrl, b, b, b)],
        dim=-2,
    )
