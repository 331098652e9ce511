"""Area-weighted Chamfer distance and normal alignment (the paper's L_Ch and L_normal).

Patch side: unsquared distance to the nearest target point, weighted by the Jacobian |J(s,t)|
and normalised by the sum of the weights. Target side: plain mean over target points of the
distance to the nearest patch sample. Nearest neighbours come from train.nn_search (k-d tree on
CPU), distances are recomputed in torch so gradients flow.

Part groups (the paper's cars: wheels and body apart): with ``Groups``, a patch sample is matched
only to target points of its group and vice versa, and each group's two means are taken on
their own and summed. One search serves all groups: each group's copy of both point sets is
shifted far along x, so a nearest neighbour is always found in the same group.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from train.nn_search import gather_points, nearest_indices

_FAR = 1e6  # masked-out patch samples are moved here for the search so they are never chosen
_GROUP_SHIFT = 100.0  # x offset between part groups in the search (models lie in the unit sphere)


class Matches(NamedTuple):
    patch_to_target: Tensor  # (B, Q) index into target points
    target_to_patch: Tensor  # (B, M) index into flattened patch samples


class Groups(NamedTuple):
    """Part group per patch and per target point, each in ``0 .. count-1``."""

    patch: Tensor  # (P,) long
    target: Tensor  # (B, M) long
    count: int

    def per_sample(self, patch_points: Tensor) -> Tensor:
        """Group of every flattened patch sample ``(B, Q)`` for ``patch_points (B, P, S, 3)``."""
        b, p, s = patch_points.shape[:3]
        return self.patch.to(patch_points.device)[None, :, None].expand(b, p, s).reshape(b, -1)


def _shifted(points: Tensor, groups: Tensor | None) -> Tensor:
    if groups is None:
        return points
    shift = torch.zeros_like(points)
    shift[..., 0] = groups.to(points.dtype) * _GROUP_SHIFT
    return points + shift


def group_mean(values: Tensor, weights: Tensor | None, groups: Tensor | None, count: int = 1) -> Tensor:
    """Σ over groups of the (weighted) mean of ``values (B, Q)`` within the group → ``(B,)``;
    a group with no weight adds 0."""
    w = torch.ones_like(values) if weights is None else weights
    if groups is None:
        return (values * w).sum(-1) / w.sum(-1).clamp_min(1e-12)
    num = values.new_zeros(values.shape[0], count).scatter_add(1, groups, values * w)
    den = values.new_zeros(values.shape[0], count).scatter_add(1, groups, w)
    return (num / den.clamp_min(1e-12)).sum(-1)


def _flat(x: Tensor, tail: int) -> Tensor:
    return x.reshape(x.shape[0], -1, *x.shape[x.dim() - tail :]) if tail else x.reshape(x.shape[0], -1)


def match_points(
    patch_points: Tensor,
    target_points: Tensor,
    valid: Tensor | None = None,
    groups: Groups | None = None,
    normals: tuple[Tensor, Tensor] | None = None,
    normal_weight: float = 0.0,
) -> Matches:
    """Nearest neighbours both ways. ``patch_points (B, P, S, 3)`` flattened to ``(B, Q, 3)``;
    ``valid (B, P, S)`` excludes samples (e.g. patches of an absent optional part); ``groups``
    keeps matches inside part groups.

    Normal-aware matching: with ``normal_weight`` λ > 0 and ``normals`` = (patch normals
    ``(B, P, S, 3)``, target normals ``(B, M, 3)``) the search runs on (x, λ·n), so a point is
    matched to the nearest point *facing the same way*. On a thin wall the nearest target point
    of a patch is often on the far side (opposite normal); plain matching then pulls the patch
    through the wall. Opposite normals add 2λ to the search distance, so λ above the half wall
    thickness keeps matches on the near side. Only the choice of partner changes: the losses
    still measure plain 3-D distances to it."""
    pp, target, search = matching_sets(patch_points, target_points, valid, groups, normals, normal_weight)
    return Matches(nearest_indices(pp, target), nearest_indices(target, search))


def matching_sets(
    patch_points: Tensor,
    target_points: Tensor,
    valid: Tensor | None = None,
    groups: Groups | None = None,
    normals: tuple[Tensor, Tensor] | None = None,
    normal_weight: float = 0.0,
) -> tuple[Tensor, Tensor, Tensor]:
    """The point sets ``match_points`` searches (detached): patch samples and target, shifted
    apart by group and extended by λ·normal as asked, and the patch samples with invalid ones
    moved far away (the reference of the target → patch search)."""
    pp = _flat(patch_points, 1).detach()
    target = target_points.detach()
    if groups is not None:
        pp, target = _shifted(pp, groups.per_sample(patch_points)), _shifted(target, groups.target)
    if normal_weight > 0:
        if normals is None:
            raise ValueError("normal-aware matching needs patch and target normals")
        pn, tn = normals
        pp = torch.cat([pp, normal_weight * _flat(pn, 1).detach().to(pp.dtype)], -1)
        target = torch.cat([target, normal_weight * tn.detach().to(target.dtype)], -1)
    search = pp
    if valid is not None:
        search = torch.where(_flat(valid, 0)[..., None], search, torch.full_like(search, _FAR))
    return pp, target, search


def _weights(jacobian: Tensor, valid: Tensor | None) -> Tensor:
    w = _flat(jacobian, 0)
    return w if valid is None else w * _flat(valid, 0).to(w.dtype)


def chamfer_loss(
    patch_points: Tensor,
    jacobian: Tensor,
    target_points: Tensor,
    valid: Tensor | None = None,
    matches: Matches | None = None,
    groups: Groups | None = None,
) -> Tensor:
    """L_Ch per batch item ``(B,)``. ``patch_points (B, P, S, 3)``, ``jacobian (B, P, S)``,
    ``target_points (B, M, 3)``; optional ``valid (B, P, S)`` or broadcastable mask; ``groups``
    gives the sum of per-group L_Ch."""
    pp = _flat(patch_points, 1)
    if valid is not None:
        valid = valid.expand(jacobian.shape)
    m = matches or match_points(patch_points, target_points, valid, groups)
    w = _weights(jacobian, valid)
    d_pt = torch.sqrt(((pp - gather_points(target_points, m.patch_to_target)) ** 2).sum(-1).clamp_min(1e-24))
    d_tp = torch.sqrt(((target_points - gather_points(pp, m.target_to_patch)) ** 2).sum(-1).clamp_min(1e-24))
    return _two_sided(d_pt, w, d_tp, patch_points, groups)


def _two_sided(d_pt: Tensor, w: Tensor, d_tp: Tensor, patch_points: Tensor, groups: Groups | None) -> Tensor:
    if groups is None:
        return group_mean(d_pt, w, None) + d_tp.mean(-1)
    return group_mean(d_pt, w, groups.per_sample(patch_points), groups.count) + group_mean(
        d_tp, None, groups.target.to(d_tp.device), groups.count
    )


def normal_alignment_loss(
    patch_normals: Tensor,
    jacobian: Tensor,
    target_normals: Tensor,
    matches: Matches,
    valid: Tensor | None = None,
    groups: Groups | None = None,
) -> Tensor:
    """L_normal per batch item: ‖n_x − n_y‖² between matched points, Jacobian-weighted on the
    patch side and a plain mean on the target side. ``matches`` from ``match_points`` (with the
    same ``groups``)."""
    pn = _flat(patch_normals, 1)
    if valid is not None:
        valid = valid.expand(jacobian.shape)
    w = _weights(jacobian, valid)
    d_pt = ((pn - gather_points(target_normals, matches.patch_to_target)) ** 2).sum(-1)
    d_tp = ((target_normals - gather_points(pn, matches.target_to_patch)) ** 2).sum(-1)
    return _two_sided(d_pt, w, d_tp, patch_normals, groups)
