"""The paper's weighted total loss over one batch of patches."""

from __future__ import annotations

from torch import Tensor

from train.geometry.patch_pairs import CollisionPairs
from train.losses.chamfer import Groups
from train.losses.terms import LOSS_TERMS, TermInputs
from train.losses.weights import LossWeights

TERMS = tuple(t.name for t in LOSS_TERMS)


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
    match_normals: float = 0.0,
    fit_points: Tensor | None = None,
    fit_weight: Tensor | None = None,
) -> dict[str, Tensor]:
    """Each unweighted term of the loss per batch item ``(B,)``, keyed by ``TERMS`` (the term table,
    ``train.losses.terms``).

    ``patches (B, P, 4, 4, 3)`` sampled at ``st (S, 2)`` or ``(P, S, 2)``; targets ``(B, M, 3)``.
    ``patch_mask (B, P)`` bool drops patches (absent optional parts) from every term;
    the symmetry term, which acts on control points, takes ``symmetry_valid (B, K)`` for that.
    ``template_normals`` are the template's normals at the same ``st``;
    ``control_points (B, N, 3)`` + ``symmetry_pairs (K, 2)`` feed the symmetry term;
    ``collision`` pairs feed the collision term; ``groups`` splits Chamfer and normal terms by
    part group; ``match_normals`` > 0 pairs points by position and normal (``match_points``);
    ``fit_points (B, N, 3)`` + ``fit_weight (B, N)`` (the fit stage's control points and which
    count) feed the fit term, with ``control_points``.
    A term whose weight is 0 or whose inputs are
    missing is skipped (reported as 0), which is how ablations save time.
    """
    x = TermInputs(
        patches,
        st,
        target_points,
        target_normals,
        patch_mask,
        template_normals,
        control_points,
        symmetry_pairs,
        symmetry_valid,
        plane_x,
        collision,
        groups,
        match_normals,
        fit_points,
        fit_weight,
    )
    zero = patches.new_zeros(patches.shape[0])
    terms: dict[str, Tensor] = {}
    for term in LOSS_TERMS:
        value = term.fn(x) if getattr(weights, term.name) else None
        terms[term.name] = zero if value is None else value
    return terms
