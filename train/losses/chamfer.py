"""Area-weighted Chamfer distance and normal alignment (the paper's L_Ch and L_normal).

Patch side: unsquared distance to the nearest target point, weighted by the Jacobian |J(s,t)|
and normalised by the sum of the weights. Target side: plain mean over target points of the
distance to the nearest patch sample. Nearest neighbours come from train.nn_search (k-d tree on
CPU), distances are recomputed in torch so gradients flow.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from train.nn_search import gather_points, nearest_indices

_FAR = 1e6  # masked-out patch samples are moved here for the search so they are never chosen


class Matches(NamedTuple):
    patch_to_target: Tensor  # (B, Q) index into target points
    target_to_patch: Tensor  # (B, M) index into flattened patch samples


def _flat(x: Tensor, tail: int) -> Tensor:
    return x.reshape(x.shape[0], -1, *x.shape[x.dim() - tail :]) if tail else x.reshape(x.shape[0], -1)


def match_points(patch_points: Tensor, target_points: Tensor, valid: Tensor | None = None) -> Matches:
    """Nearest neighbours both ways. ``patch_points (B, ..., 3)`` flattened to ``(B, Q, 3)``;
    ``valid (B, ...)`` excludes samples (e.g. patches of an absent optional part)."""
    pp = _flat(patch_points, 1)
    search = pp.detach()
    if valid is not None:
        search = torch.where(_flat(valid, 0)[..., None], search, torch.full_like(search, _FAR))
    return Matches(nearest_indices(pp, target_points), nearest_indices(target_points, search))


def _weights(jacobian: Tensor, valid: Tensor | None) -> Tensor:
    w = _flat(jacobian, 0)
    return w if valid is None else w * _flat(valid, 0).to(w.dtype)


def chamfer_loss(
    patch_points: Tensor,
    jacobian: Tensor,
    target_points: Tensor,
    valid: Tensor | None = None,
    matches: Matches | None = None,
) -> Tensor:
    """L_Ch per batch item ``(B,)``. ``patch_points (B, P, S, 3)``, ``jacobian (B, P, S)``,
    ``target_points (B, M, 3)``; optional ``valid (B, P, S)`` or broadcastable mask."""
    pp = _flat(patch_points, 1)
    if valid is not None:
        valid = valid.expand(jacobian.shape)
    m = matches or match_points(patch_points, target_points, valid)
    w = _weights(jacobian, valid)
    d_pt = torch.sqrt(((pp - gather_points(target_points, m.patch_to_target)) ** 2).sum(-1).clamp_min(1e-24))
    d_tp = torch.sqrt(((target_points - gather_points(pp, m.target_to_patch)) ** 2).sum(-1).clamp_min(1e-24))
    return (d_pt * w).sum(-1) / w.sum(-1).clamp_min(1e-12) + d_tp.mean(-1)


def normal_alignment_loss(
    patch_normals: Tensor,
    jacobian: Tensor,
    target_normals: Tensor,
    matches: Matches,
    valid: Tensor | None = None,
) -> Tensor:
    """L_normal per batch item: ‖n_x − n_y‖² between matched points, Jacobian-weighted on the
    patch side and a plain mean on the target side. ``matches`` from ``match_points``."""
    pn = _flat(patch_normals, 1)
    if valid is not None:
        valid = valid.expand(jacobian.shape)
    w = _weights(jacobian, valid)
    d_pt = ((pn - gather_points(target_normals, matches.patch_to_target)) ** 2).sum(-1)
    d_tp = ((target_normals - gather_points(pn, matches.target_to_patch)) ** 2).sum(-1)
    return (d_pt * w).sum(-1) / w.sum(-1).clamp_min(1e-12) + d_tp.mean(-1)
