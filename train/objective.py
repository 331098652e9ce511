"""The paper's loss bound to one template: its sample layout, collision pairs, symmetry pairs
and template normals are computed once, then every batch calls ``batch_terms`` (or ``terms``).

Part structure reaches every term here: ``patch_mask`` turns patches of a model's absent optional
parts off (and the template's closing patches for that part on), from the shard's
``present_parts``; ``groups`` splits Chamfer and normal terms by the template's ``part_groups``
using the shard's per-point part labels. A batch from a ``--fit-patches`` build also carries
each model's fitted parameters, the fit term's target (its present patches' control points)."""

from __future__ import annotations

import dataclasses
import math

import torch
from torch import Tensor

from pipeline.core.schema import POINT_PART_NAMES, PRESENT_PARTS
from train.errors import UsageError
from train.geometry.coons import evaluate_patches
from train.geometry.patch_pairs import CollisionPairs, collision_pairs
from train.losses.chamfer import Groups
from train.losses.fit_target import fit_target_loss
from train.losses.total import loss_terms
from train.losses.weights import LossWeights
from train.templates import Template


@dataclasses.dataclass
class _Resident:
    """The template's constants as every step uses them, on one device: copied there once, so a
    step makes no host-to-device copy or host-side computation of things that never change."""

    template_patches: Tensor  # (1, P, 4, 4, 3)
    sym: Tensor  # (K, 2) long
    patch_points: Tensor  # (P, N) float: the incidence, as used_points multiplies it
    any_patch_point: Tensor  # (N,) bool: points some patch depends on
    patch_group: Tensor  # (P,) long
    pairs: CollisionPairs
    masks: dict[frozenset[str] | None, Tensor]  # (P,) bool patch mask per set of present parts


class Objective:
    """Loss terms of a template's patches against target points, per batch item."""

    def __init__(
        self,
        template: Template,
        n_points: int = 7000,
        collision_grid: int = 8,
        match_normals: float = 0.0,
        leave_out: tuple[str, ...] = (),
        collision_truncate: int = 1,
    ):
        self.template = template
        unknown = sorted(set(leave_out) - set(template.patch_labels))
        if unknown:
            raise ValueError(
                f"no patches labelled {', '.join(unknown)} in the template "
                f"(its labels: {', '.join(sorted(set(template.patch_labels)))})"
            )
        # parts no target has (real car bodies without wheels): absent in every mask, so an
        # optional part's closing patches close the surface where it was
        self.leave_out = frozenset(leave_out)
        self.keep = torch.tensor([lab not in leave_out for lab in template.patch_labels], dtype=torch.bool)
        self.match_normals = match_normals  # λ of normal-aware matching in training (metrics: plain)
        self.side = max(2, math.ceil(math.sqrt(n_points / template.num_patches)))  # k² samples per patch
        # grid rows left out along a seam two patches share (0: only the shared corners; crossings up to the seam count)
        self.pairs = collision_pairs(template, grid=collision_grid, truncate=collision_truncate)
        self.sym = template.symmetry_pairs()
        self.plane_x = template.symmetry.plane_x if template.symmetry else 0.0
        with torch.no_grad():
            self.template_patches = template.patches_from_params(template.initial_params()[None])
        self.patch_points = _patch_point_incidence(template)  # (P, N) bool
        group_names = list(template.part_groups)
        self.group_of_label = {lab: g for g, name in enumerate(group_names) for lab in template.part_groups[name]}
        self.n_groups = len(group_names) + 1  # labels in no group form the last one
        self.patch_group = torch.tensor(
            [self.group_of_label.get(lab, len(group_names)) for lab in template.patch_labels], dtype=torch.long
        )
        self._resident: dict[torch.device, _Resident] = {}

    def resident(self, device: torch.device) -> _Resident:
        """The constants on ``device`` (made on the first step that runs there)."""
        device = torch.device(device)
        if device not in self._resident:
            with torch.inference_mode(False):  # kept for later steps, which autograd records
                self._resident[device] = self._make_resident(device)
        return self._resident[device]

    def _make_resident(self, device: torch.device) -> _Resident:
        return _Resident(
            self.template_patches.to(device),
            self.sym.to(device),
            self.patch_points.to(device).float(),
            self.patch_points.any(0).to(device),
            self.patch_group.to(device),
            self.pairs.to(device),
            {},
        )

    def sample_st(self, generator: torch.Generator | None) -> Tensor:
        """Uniform random (s, t) samples (S, 2) when given a generator, else a midpoint grid."""
        n = self.side * self.side
        if generator is not None:
            return torch.rand(n, 2, generator=generator)
        g = (torch.arange(self.side) + 0.5) / self.side
        return torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)

    def patch_mask(self, metas: list[dict], device: torch.device) -> Tensor | None:
        """(B, P) bool: patches of optional parts a model lacks are off (e.g. engines), and the
        template's closing patches of a part are on only when the part is absent. A model
        without ``present_parts`` (a source without part labels) counts as having every part.
        Patches of the labels left out (``leave_out``) are off for every model; a left-out optional
        part counts as absent, so its closing patches are on."""
        if not self.template.part_names:
            if bool(self.keep.all()):
                return None
            return self.keep.to(device).expand(len(metas), -1)
        return torch.stack([self._mask_on(device, (meta or {}).get(PRESENT_PARTS)) for meta in metas])

    def _mask_on(self, device: torch.device, present: list[str] | None) -> Tensor:
        """``mask_for(present)`` on ``device``, made once per set of parts (a batch repeats a few)."""
        masks = self.resident(device).masks
        key = None if present is None else frozenset(present)
        if key not in masks:
            with torch.inference_mode(False):
                masks[key] = self.mask_for(present).to(device)
        return masks[key]

    def mask_for(self, present: list[str] | None) -> Tensor:
        """(P,) bool patch mask for a model with the part families ``present`` (None: all), from
        the template's own rule (``Template.active_patches``). Labels that name none of the
        template's parts (a folder's own part names under a built-in template) say nothing about
        them: every part counts as present then, as without labels."""
        if present is not None and not set(present) & set(self.template.patch_labels):
            present = None
        parts = {p: (present is None or p in present) and p not in self.leave_out for p in self.template.part_names}
        mask = torch.zeros(self.template.num_patches, dtype=torch.bool)
        mask[self.template.active_patches(parts)] = True
        return mask & self.keep

    def groups(self, batch: dict, device: torch.device) -> Groups | None:
        """Part group of each target point from the shard's per-point labels, or None when the
        template declares no groups or a sample lacks labels (then one group: the whole shape)."""
        if self.n_groups == 1 or "point_parts" not in batch:
            return None
        ids = batch["point_parts"]
        if (ids < 0).any():
            return None
        rows = []
        for b, meta in enumerate(batch["meta"]):
            names = (meta or {}).get(POINT_PART_NAMES) or []
            lut = torch.tensor([self.group_of_label.get(n, self.n_groups - 1) for n in names] or [0], dtype=torch.long)
            rows.append(lut[ids[b].clamp(0, len(lut) - 1)])
        return Groups(self.resident(device).patch_group, torch.stack(rows).to(device, non_blocking=True), self.n_groups)

    def symmetry_valid(self, mask: Tensor | None) -> Tensor | None:
        """(B, K) bool: symmetry pairs whose two points both belong to some present patch."""
        if mask is None or not self.sym.numel():
            return None
        used = self.used_points(mask)
        sym = self.resident(mask.device).sym
        return used[:, sym[:, 0]] & used[:, sym[:, 1]]

    def used_points(self, mask: Tensor) -> Tensor:
        """(B, N) bool: template points some present patch depends on."""
        return (mask.float() @ self.resident(mask.device).patch_points) > 0

    def fit_targets(
        self, batch: dict, mask: Tensor | None, device: torch.device
    ) -> tuple[Tensor, Tensor] | tuple[None, None]:
        """The fit term's inputs from a batch: the fitted control points (B, N, 3) and which count
        (B, N) (present patches' points of items with a valid fit); (None, None) when the batch
        has no valid fit target."""
        fit = batch.get("fit_params")
        if fit is None or not bool(batch["fit_valid"].any()):
            return None, None
        if fit.shape[-1] != self.template.num_params:
            raise UsageError(
                f"{batch['key'][0]}: fitted parameters have {fit.shape[-1]} values, template "
                f"{self.template.name or '?'} has {self.template.num_params}: the dataset was fitted to another template"
            )
        with torch.no_grad():
            points = self.template.points_from_params(fit.to(device, non_blocking=True))
        used = self.resident(device).any_patch_point[None].expand(fit.shape[0], -1)
        if mask is not None:
            used = self.used_points(mask)
        return points, used & batch["fit_valid"].to(device, non_blocking=True)[:, None]

    def readout_term(self, params: Tensor, batch: dict) -> Tensor | None:
        """The fit term (B,) of a training-only readout's parameters ``params (B, D)``
        (``--fit-readout``): its control points against the batch's fitted ones, present patches
        only; None when the batch has no valid fit target."""
        dev = params.device
        fit_points, fit_weight = self.fit_targets(batch, self.patch_mask(batch["meta"], dev), dev)
        if fit_points is None:
            return None
        return fit_target_loss(self.template.points_from_params(params), fit_points, fit_weight)

    def batch_terms(
        self, params: Tensor, batch: dict, st: Tensor, weights: LossWeights, training: bool = True
    ) -> dict[str, Tensor]:
        """``terms`` for a loader batch: target points, patch mask and (``training``) part groups
        and normal-aware matching. Metrics use ``training=False``: the plain L_Ch (nearest points,
        no groups), comparable across templates and settings."""
        dev = params.device
        mask = self.patch_mask(batch["meta"], dev)
        fit_points, fit_weight = self.fit_targets(batch, mask, dev) if weights.fit else (None, None)
        return self.terms(
            params,
            batch["points"].to(dev, non_blocking=True),
            st,
            mask,
            weights,
            self.groups(batch, dev) if training else None,
            self.match_normals if training else 0.0,
            fit_points,
            fit_weight,
        )

    def terms(
        self,
        params: Tensor,
        points: Tensor,
        st: Tensor,
        mask: Tensor | None,
        weights: LossWeights,
        groups: Groups | None = None,
        match_normals: float = 0.0,
        fit_points: Tensor | None = None,
        fit_weight: Tensor | None = None,
    ) -> dict[str, Tensor]:
        """Each term per batch item (B,) for network outputs ``params (B, D)`` and target
        ``points (B, M, 6)`` (xyz + normal); terms with weight 0 are skipped. ``fit_points`` and
        ``fit_weight`` (``fit_targets``) feed the fit term."""
        # drawn on the host by the step's seeded generator: one small copy, not waited for
        st = st.to(params.device, non_blocking=True)
        on = self.resident(params.device)
        template_normals = None
        if weights.template_normal or weights.fold:
            template_normals = evaluate_patches(on.template_patches, st).normals[0]
        patches, control_points = self.template.patches_and_points(params)
        return loss_terms(
            patches,
            st,
            points[..., :3],
            points[..., 3:],
            weights,
            patch_mask=mask,
            template_normals=template_normals,
            control_points=control_points if self.sym.numel() or fit_points is not None else None,
            symmetry_pairs=on.sym if self.sym.numel() else None,
            symmetry_valid=self.symmetry_valid(mask),
            plane_x=self.plane_x,
            collision=on.pairs,
            groups=groups,
            match_normals=match_normals,
            fit_points=fit_points,
            fit_weight=fit_weight,
        )


def _patch_point_incidence(template: Template) -> Tensor:
    """(P, N) bool: which template points a patch's geometry depends on (its curves' control
    points, through sub-curves to their parents and junction points to their host curves)."""
    from functools import cache

    from train.templates.template import JunctionPoint

    @cache
    def point_deps(pi: int) -> frozenset[int]:
        p = template.points[pi]
        return frozenset({pi}) | (curve_deps(p.curve) if isinstance(p, JunctionPoint) else frozenset())

    @cache
    def curve_deps(ci: int) -> frozenset[int]:
        c = template.curves[ci]
        if not c.is_sub:
            return frozenset().union(*(point_deps(p) for p in c.points))
        return point_deps(c.start) | point_deps(c.end) | curve_deps(c.parent)

    out = torch.zeros(template.num_patches, template.num_points, dtype=torch.bool)
    for pi, patch in enumerate(template.patches):
        out[pi, sorted(frozenset().union(*(curve_deps(ci) for ci in patch.curves)))] = True
    return out
