"""The paper's weighted total loss over one batch of patches."""

from __future__ import annotations

from torch import Tensor

from train.geometry.coons import evaluate_patches
from train.losses.chamfer import Groups, chamfer_loss, match_points, normal_alignment_loss
from train.losses.collision import CollisionPairs, collision_loss
from train.losses.regularizers import flatness_loss, symmetry_loss, template_normal_loss
from train.losses.weights import LossWeights


TERMS = ("chamfer", "normal", "flat", "collision", "template_normal", "symmetry")


def weighted_sum(terms: dict[str, Tensor], weights: LossWeights) -> Tensor:
    """Σ weight × term, per batch item (the terms are ``(B,)``)."""
    return sum(getattr(weights, name) * terms[name] for name in TERMS)


def total_loss(
    patches: Tensor,
    st: Tensor,
    target_points: Tensor,
    target_normals: Tensor,
    weights: LossWeights = LossWeights(),
    **inputs,
) -> tuple[Tensor, dict[str, Tensor]]:
    """Weighted sum L = L_Ch + α_n L_normal + α_flat L_flat + α_coll L_coll + α_T L_template + α_sym L_sym.

    Takes the arguments of :func:`loss_terms`. Returns the batch mean and a dict of unweighted
    per-term batch means (tensors; the total keeps its graph).
    """
    terms = loss_terms(patches, st, target_points, target_normals, weights, **inputs)
    return weighted_sum(terms, weights).mean(), {name: value.mean() for name, value in terms.items()}


def loss_terms(
    patches: Tensor,
    st: Tensor,
    target_points: Tensor,
    target_normals: Tensor,
    weights: LossWeights = LossWeights(),
    *,
    patch_mask: Tensor | None = None,
    template_normals: Tensor | None = None,
    control_points: Tensor | None = None,
    symmetry_pairs: Tensor | None = None,
    symmetry_valid: Tensor | None = None,
    plane_x: float = 0.0,
    collision: CollisionPairs | None = None,
    groups: Groups | None = None,
) -> dict[str, Tensor]:
    """Each unweighted term of the paper's loss per batch item ``(B,)``, keyed by ``TERMS``.

    ``patches (B, P, 4, 4, 3)`` sampled at ``st (S, 2)`` or ``(P, S, 2)``; targets ``(B, M, 3)``.
    ``patch_mask (B, P)`` bool drops patches (absent optional parts) from every term;
    the symmetry term, which acts on control points, takes ``symmetry_valid (B, K)`` for that.
    ``template_normals`` are the template's normals at the same ``st``;
    ``control_points (B, N, 3)`` + ``symmetry_pairs (K, 2)`` feed the symmetry term;
    ``collision`` pairs feed the collision term; ``groups`` splits Chamfer and normal terms by
    part group. A term whose weight is 0 or whose inputs are
    missing is skipped (reported as 0), which is how ablations save time.
    """
    bsz = patches.shape[0]
    zero = patches.new_zeros(bsz)
    ev = evaluate_patches(patches, st)
    valid = None if patch_mask is None else patch_mask[..., None].expand(ev.jacobian.shape)
    terms: dict[str, Tensor] = {}
    need_match = weights.chamfer != 0 or weights.normal != 0
    matches = match_points(ev.points, target_points, valid, groups) if need_match else None
    terms["chamfer"] = chamfer_loss(ev.points, ev.jacobian, target_points, valid, matches, groups) if weights.chamfer else zero
    terms["normal"] = (
        normal_alignment_loss(ev.normals, ev.jacobian, target_normals, matches, valid, groups) if weights.normal else zero
    )
    terms["flat"] = flatness_loss(ev.points, st, ev.jacobian, valid) if weights.flat else zero
    terms["collision"] = (
        collision_loss(patches, collision, patch_mask=patch_mask) if weights.collision and collision is not None else zero
    )
    terms["template_normal"] = (
        template_normal_loss(ev.normals, template_normals.to(patches.dtype), ev.jacobian, valid)
        if weights.template_normal and template_normals is not None
        else zero
    )
    terms["symmetry"] = (
        symmetry_loss(control_points, symmetry_pairs, plane_x, symmetry_valid)
        if weights.symmetry and control_points is not None and symmetry_pairs is not None
        else zero
    )
    return terms
