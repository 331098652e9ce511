"""The table of loss terms: one ``LossTerm`` entry per term of the training loss.

An entry gives the term's name, the function computing it per batch item, whether the trainer
offers a ``--no-<name>`` ablation flag, and whether it is a regularizer a template file switches
on (off unless the template's ``regularizers`` name it). Its default weight is the field of the
same name in ``train.losses.weights.LossWeights`` (a test keeps the two in step). The
``--w-<name>`` / ``--no-<name>`` flags, ``loss_terms`` (and so ``Objective.terms``) and the
training log's columns are made from this table, so a new term is one entry in ``LOSS_TERMS``
and one field in ``LossWeights``. Its function gets the batch as a ``TermInputs`` and returns
``(B,)``, or None when its inputs are missing (reported as 0).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable

from torch import Tensor

from train.geometry.coons import PatchSamples, evaluate_patches
from train.geometry.patch_pairs import CollisionPairs
from train.losses.chamfer import Groups, Matches, chamfer_loss, match_points, normal_alignment_loss
from train.losses.collision import collision_loss
from train.losses.fit_target import fit_target_loss
from train.losses.regularizers import flatness_loss, fold_loss, symmetry_loss, template_normal_loss


@dataclass
class TermInputs:
    """One batch as the terms see it (shapes as in ``loss_terms``); patch samples and
    point matches are computed once, on first use, and shared by the terms needing them."""

    patches: Tensor
    st: Tensor
    target_points: Tensor
    target_normals: Tensor
    patch_mask: Tensor | None = None
    template_normals: Tensor | None = None
    control_points: Tensor | None = None
    symmetry_pairs: Tensor | None = None
    symmetry_valid: Tensor | None = None
    plane_x: float = 0.0
    collision: CollisionPairs | None = None
    groups: Groups | None = None
    match_normals: float = 0.0  # λ of normal-aware matching (0: nearest point, the paper's metric)
    fit_points: Tensor | None = None  # (B, N, 3) the fit stage's control points (a --fit-patches build)
    fit_weight: Tensor | None = None  # (B, N) which of them count (present patches, items with a fit)

    @functools.cached_property
    def ev(self) -> PatchSamples:
        return evaluate_patches(self.patches, self.st)

    @functools.cached_property
    def valid(self) -> Tensor | None:
        """(B, P, S) bool: samples of present patches (None: all)."""
        return None if self.patch_mask is None else self.patch_mask[..., None].expand(self.ev.jacobian.shape)

    @functools.cached_property
    def matches(self) -> Matches:
        normals = (self.ev.normals, self.target_normals) if self.match_normals else None
        return match_points(self.ev.points, self.target_points, self.valid, self.groups, normals, self.match_normals)


@dataclass(frozen=True)
class LossTerm:
    name: str
    fn: Callable[[TermInputs], Tensor | None]
    ablation: bool = True  # the trainer offers --no-<name>
    regularizer: bool = False  # off unless the template file names it (Template.regularizers)


def _chamfer(x: TermInputs) -> Tensor:
    return chamfer_loss(x.ev.points, x.ev.jacobian, x.target_points, x.valid, x.matches, x.groups)


def _normal(x: TermInputs) -> Tensor:
    return normal_alignment_loss(x.ev.normals, x.ev.jacobian, x.target_normals, x.matches, x.valid, x.groups)


def _flat(x: TermInputs) -> Tensor:
    return flatness_loss(x.ev.points, x.st, x.ev.jacobian, x.valid)


def _collision(x: TermInputs) -> Tensor | None:
    return None if x.collision is None else collision_loss(x.patches, x.collision, patch_mask=x.patch_mask)


def _template_normal(x: TermInputs) -> Tensor | None:
    if x.template_normals is None:
        return None
    return template_normal_loss(x.ev.normals, x.template_normals.to(x.patches.dtype), x.ev.jacobian, x.valid)


def _fold(x: TermInputs) -> Tensor | None:
    if x.template_normals is None:
        return None
    return fold_loss(x.ev.normals, x.ev.jacobian, x.template_normals.to(x.patches.dtype), x.valid)


def _symmetry(x: TermInputs) -> Tensor | None:
    if x.control_points is None or x.symmetry_pairs is None:
        return None
    return symmetry_loss(x.control_points, x.symmetry_pairs, x.plane_x, x.symmetry_valid)


def _fit(x: TermInputs) -> Tensor | None:
    if x.control_points is None or x.fit_points is None or x.fit_weight is None:
        return None
    return fit_target_loss(x.control_points, x.fit_points, x.fit_weight)


LOSS_TERMS: tuple[LossTerm, ...] = (
    LossTerm("chamfer", _chamfer, ablation=False),
    LossTerm("normal", _normal),
    LossTerm("flat", _flat),
    LossTerm("collision", _collision),
    LossTerm("template_normal", _template_normal, regularizer=True),
    LossTerm("symmetry", _symmetry, regularizer=True),
    LossTerm("fit", _fit, ablation=False),  # off by default (weight 0): --w-fit, a fitted dataset
    LossTerm("fold", _fold, ablation=False),  # off by default (weight 0): --w-fold, not in the paper
)


def regularizer_names() -> tuple[str, ...]:
    """Terms a template file may name in ``regularizers``."""
    return tuple(t.name for t in LOSS_TERMS if t.regularizer)
