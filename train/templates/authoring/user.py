"""A template for any category from per-model part boxes (the paper's rules on real data).

Input: models, each with its part boxes and surface samples in the normalized frame (from
segmented meshes, connected components, or a cuboid file). Then, as for the built-in categories:

* presence: the share of models having each part label; a part in at least
  ``presence_threshold`` of the models is required, one in fewer is optional (its patches can be
  switched off, closing patches seal the body), one in under ``min_presence`` is dropped;
* the median model by Chamfer distance (summed over all models) among the models having every
  required part; an optional part the median lacks is borrowed (its boxes) from the model
  nearest to the median that has it, so the template can switch every optional part;
* hollow parts (the user names them) become a floor and four walls, open at +y;
* the x = 0 mirror plane when the median's boxes pair up (``symmetry.py``): boxes are made
  exactly symmetric and the plane is recorded with the symmetry regularizer; otherwise the
  construction is not mirrored;
* the cuboids → template path of ``from_cuboids.py``, within a patch budget through
  ``budget.py`` when one is given.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from pipeline.core.settings_io import setting
from train.templates.authoring.budget import candidates, template_chamfer, within_budget
from train.templates.authoring.build import MATCH_NORMALS
from train.templates.authoring.checks import closed_manifold_problems, part_combinations
from train.templates.authoring.from_cuboids import TemplateSettings, template_from_boxes
from train.templates.authoring.lattice import Box
from train.templates.authoring.median import chamfer_matrix
from train.templates.authoring.part_boxes import hollow_box
from train.templates.authoring.symmetry import MIRROR_TOL, mirror_pairs, symmetrize
from train.templates.template import Template


class TemplateInputError(ValueError):
    """The inputs cannot make a template; the message names the model (or file and line)."""


@dataclass
class ModelBoxes:
    """One model's part boxes and surface samples, both in the normalized frame."""

    model_id: str
    boxes: list[Box]
    cloud: np.ndarray
    optional: set[str] = field(default_factory=set)  # labels the input marks optional
    origin: str = ""  # how its parts were found (groups, labels file, components, cuboids)


@dataclass(frozen=True)
class UserSettings:
    presence_threshold: float = setting(1.0, "share of models from which a part is required")
    min_presence: float = setting(0.0, "parts in fewer models are dropped")
    snap_tol: float = 0.01
    symmetry: str = setting("auto", "auto | x | none")
    mirror_tol: float = MIRROR_TOL
    budget: int | None = setting(None, "max patches (None: the full construction)")
    hollow: dict[str, tuple[float, float]] = field(default_factory=dict)  # label -> (wall, bottom)
    part_groups: dict[str, list[str]] = field(default_factory=dict)
    seed: int = 0


@dataclass
class UserResult:
    template: Template
    chosen: str
    presence: dict[str, float]
    required: list[str]
    optional: list[str]
    dropped: list[str]
    borrowed: dict[str, str]
    symmetric: bool
    mirror_pairs: int
    chamfer_sums: dict[str, float]
    failures: dict[str, str]

    def report(self) -> str:
        """Human-readable summary: presence of every part, the median, symmetry."""
        t = self.template
        lines = [
            f"{t.name}: {t.num_patches} patches, {t.num_params} parameters, median model {self.chosen}, "
            f"Chamfer to it {t.metadata['chamfer_to_median']:.4f}",
            f"  symmetry: {'x = 0 plane' if self.symmetric else 'none'} ({self.mirror_pairs} mirror pairs in the median)",
        ]
        for lab, p in sorted(self.presence.items(), key=lambda kv: (-kv[1], kv[0])):
            kind = "required" if lab in self.required else "optional" if lab in self.optional else "dropped (rare)"
            if lab in self.optional and lab not in t.patch_labels:
                kind += ", left out by the patch budget"
            extra = f", boxes from {self.borrowed[lab]}" if lab in self.borrowed else ""
            lines.append(f"  part {lab}: in {p:.0%} of models -> {kind}{extra}")
        for mid, why in sorted(self.failures.items()):
            lines.append(f"  skipped {mid}: {why}")
        return "\n".join(lines)


def part_presence(models: Sequence[ModelBoxes]) -> dict[str, float]:
    """Share of models with at least one box of each label."""
    n = len(models)
    counts: dict[str, int] = {}
    for m in models:
        for lab in {b.label for b in m.boxes}:
            counts[lab] = counts.get(lab, 0) + 1
    return {lab: c / n for lab, c in sorted(counts.items())}


def check_consistent(models: Sequence[ModelBoxes]) -> None:
    """Raise when a model shares no part label with any other model (labels named differently)."""
    if len(models) < 2:
        return
    labels = [{b.label for b in m.boxes} for m in models]
    for i, m in enumerate(models):
        others = set().union(*(s for j, s in enumerate(labels) if j != i))
        if labels[i] and not labels[i] & others:
            raise TemplateInputError(
                f"{m.model_id}: its part labels {sorted(labels[i])} appear in no other model (the others use "
                f"{sorted(others)[:12]}); inconsistent labels across models: map them to common names with --part-map"
            )


def build_user_template(
    models: Sequence[ModelBoxes],
    name: str,
    settings: UserSettings = UserSettings(),
    skipped: dict[str, str] | None = None,
) -> UserResult:
    """The category template of ``models`` (see the module docstring); ``skipped``: models the
    caller could not read, {id: why}, carried into the report."""
    if not 0 < settings.presence_threshold <= 1 or not 0 <= settings.min_presence <= settings.presence_threshold:
        raise TemplateInputError("need 0 <= min_presence <= presence_threshold <= 1, presence_threshold > 0")
    failures = {**(skipped or {}), **{m.model_id: "no usable parts" for m in models if not m.boxes}}
    models = [m for m in models if m.boxes]
    if not models:
        raise TemplateInputError(f"{name}: no model has usable parts ({failures})")
    check_consistent(models)
    presence = part_presence(models)
    dropped = sorted(lab for lab, p in presence.items() if p < settings.min_presence)
    flagged = set().union(*(m.optional for m in models))
    required = sorted(lab for lab, p in presence.items() if p >= settings.presence_threshold and lab not in flagged)
    optional = sorted(lab for lab in presence if lab not in required and lab not in dropped)
    models = [dataclasses.replace(m, boxes=[b for b in m.boxes if b.label not in dropped]) for m in models]

    dist = chamfer_matrix([m.cloud for m in models])
    sums = dist.sum(axis=1)
    labels = [{b.label for b in m.boxes} for m in models]
    complete = [i for i, s in enumerate(labels) if set(required) <= s]
    if not complete:
        raise TemplateInputError(f"{name}: no model has every required part {required}")
    chosen = min(complete, key=lambda i: (sums[i], i))
    boxes = list(models[chosen].boxes)
    borrowed = {}
    for lab in optional:
        if lab not in labels[chosen]:
            donor = min((i for i in range(len(models)) if lab in labels[i]), key=lambda i: (dist[chosen, i], i))
            boxes += [b for b in models[donor].boxes if b.label == lab]
            borrowed[lab] = models[donor].model_id
    for lab, (wall, bottom) in settings.hollow.items():
        if lab not in presence:
            raise TemplateInputError(
                f"{name}: hollow part {lab!r} is not a part of any model (parts: {sorted(presence)})"
            )
        boxes = [h for b in boxes for h in (hollow_box(b, wall, bottom) if b.label == lab else [b])]

    rep = mirror_pairs(boxes, settings.mirror_tol)
    symmetric = settings.symmetry == "x" or (settings.symmetry == "auto" and rep.symmetric)
    if symmetric:
        boxes = symmetrize(boxes, rep)
    tsettings = TemplateSettings(
        snap_tol=settings.snap_tol,
        symmetric=symmetric,
        declare_symmetry=symmetric,
        optional_labels=tuple(optional),
        part_groups=tuple((k, tuple(v)) for k, v in sorted(settings.part_groups.items())),
    )
    median = models[chosen]
    if settings.budget is None:
        tpl = template_from_boxes(boxes, name=name, settings=tsettings)
        to_median = template_chamfer(tpl, median.cloud, np.random.default_rng([settings.seed, 7919]))
        extra: dict = {}
    else:
        pick = within_budget(candidates(boxes, median.cloud, tsettings, name, settings.seed), settings.budget)
        tpl, to_median = pick.template, pick.chamfer
        extra = {
            "patch_budget": settings.budget,
            "min_part_volume": pick.coarsening.min_volume,
            "merge_labels": pick.coarsening.merge_labels,
            "snap_tol": pick.coarsening.snap_tol,
        }
    for combo in part_combinations(tpl):
        problems = closed_manifold_problems(tpl, tpl.active_patches(combo))
        if problems:  # the lattice construction guarantees this; a failure is a bug, not bad input
            raise RuntimeError(f"{name}: parts {combo}: template is not closed: {problems[:3]}")
    meta = dict(
        category=name,
        source="user",
        origin=sorted({m.origin for m in models if m.origin}),
        n_models=len(models),
        median_model=median.model_id,
        presence={k: round(v, 4) for k, v in presence.items()},
        presence_threshold=settings.presence_threshold,
        dropped_parts=dropped,
        borrowed_parts=borrowed,
        mirror_pairs=len(rep.pairs),
        chamfer_to_median=round(float(to_median), 6),
        **extra,
    )
    tpl = dataclasses.replace(
        tpl,
        metadata={**tpl.metadata, **meta},
        regularizers={"template_normal": 1e-4, **({"symmetry": 1.0} if symmetric else {})},
        match_normals=MATCH_NORMALS if settings.hollow else 0.0,
    )
    return UserResult(
        tpl,
        median.model_id,
        presence,
        required,
        optional,
        dropped,
        borrowed,
        symmetric,
        len(rep.pairs),
        {m.model_id: float(s) for m, s in zip(models, sums)},
        failures,
    )
