"""The paper's loss bound to one template: its sample layout, collision pairs, symmetry pairs
and template normals are computed once, then every batch calls ``terms``."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from train.geometry.coons import evaluate_patches
from train.losses.collision import collision_pairs
from train.losses.total import loss_terms
from train.losses.weights import LossWeights
from train.templates import Template


class Objective:
    """Loss terms of a template's patches against target points, per batch item."""

    def __init__(self, template: Template, n_points: int = 7000, collision_grid: int = 8):
        self.template = template
        self.side = max(2, math.ceil(math.sqrt(n_points / template.num_patches)))  # k² samples per patch
        self.pairs = collision_pairs(template, grid=collision_grid)
        self.sym = template.symmetry_pairs()
        self.plane_x = template.symmetry.plane_x if template.symmetry else 0.0
        with torch.no_grad():
            self.template_patches = template.patches_from_params(template.initial_params()[None])

    def sample_st(self, generator: torch.Generator | None) -> Tensor:
        """Uniform random (s, t) samples (S, 2) when given a generator, else a midpoint grid."""
        n = self.side * self.side
        if generator is not None:
            return torch.rand(n, 2, generator=generator)
        g = (torch.arange(self.side) + 0.5) / self.side
        return torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)

    def patch_mask(self, metas: list[dict], device: torch.device) -> Tensor | None:
        """(B, P) bool: patches of optional parts a model lacks are left out (e.g. turbines)."""
        if not self.template.optional_parts:
            return None
        mask = torch.ones(len(metas), self.template.num_patches, dtype=torch.bool)
        for b, meta in enumerate(metas):
            has = (meta or {}).get("has_parts", {}) or {}
            for part, patch_ids in self.template.optional_parts.items():
                if not has.get(part, True):
                    mask[b, patch_ids] = False
        return mask.to(device)

    def terms(self, params: Tensor, points: Tensor, st: Tensor, mask: Tensor | None, weights: LossWeights) -> dict[str, Tensor]:
        """Each term per batch item (B,) for network outputs ``params (B, D)`` and target
        ``points (B, M, 6)`` (xyz + normal); terms with weight 0 are skipped."""
        st = st.to(params.device)
        template_normals = None
        if weights.template_normal:
            template_normals = evaluate_patches(self.template_patches.to(params.device), st).normals[0]
        return loss_terms(
            self.template.patches_from_params(params), st, points[..., :3], points[..., 3:], weights,
            patch_mask=mask, template_normals=template_normals,
            control_points=self.template.points_from_params(params) if self.sym.numel() else None,
            symmetry_pairs=self.sym if self.sym.numel() else None, plane_x=self.plane_x,
            collision=self.pairs,
        )  # fmt: skip
