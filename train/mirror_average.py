"""Inference averaged with the mirrored drawing: a drawing flipped left to right shows the shape
mirrored across the template's symmetry plane (seen from the mirrored camera), so the network's
answer to the flipped drawing, mirrored back through the template's parameter mirror, is a second
reading of the same shape. Their mean is a two-member ensemble at twice the inference cost; it
needs a template whose parameters mirror (``train.data.param_mirror``), as training's flips do.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import nn

from train.data import param_mirror
from train.errors import UsageError
from train.fit import TrainedRun
from train.templates.template import Template


class MirrorAverage(nn.Module):
    """``model`` whose output for ``images (B, V, 1, H, W)`` is the mean of its output and the
    mirrored output for the images flipped left to right."""

    def __init__(self, model: nn.Module, template: Template) -> None:
        super().__init__()
        mirror = param_mirror(template)
        if mirror is None:
            raise UsageError(
                f"template {template.name!r} has no mirror of its parameters (no symmetry plane, or its "
                "curves do not pair up): --mirror-average needs a bilaterally symmetric template"
            )
        self.model = model
        self.register_buffer("perm", torch.as_tensor(mirror.perm, dtype=torch.long), persistent=False)
        self.register_buffer("sign", torch.as_tensor(mirror.sign, dtype=torch.float32), persistent=False)

    def forward(self, images: torch.Tensor, view_mask: torch.Tensor | None = None) -> torch.Tensor:
        both = torch.cat([images, torch.flip(images, dims=[-1])])
        mask = None if view_mask is None else torch.cat([view_mask, view_mask])
        seen, flipped = self.model(both, mask).chunk(2)
        return 0.5 * (seen + flipped[:, self.perm] * self.sign.to(flipped.dtype))


def mirror_averaged(run: TrainedRun) -> TrainedRun:
    """``run`` answering every drawing with :class:`MirrorAverage` (``--mirror-average``)."""
    return dataclasses.replace(run, model=MirrorAverage(run.model, run.template).eval())
