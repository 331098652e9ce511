"""Shape-code term: the encoder's code must tell the target's main shape variations.

The Chamfer loss reaches the encoder only through the output layer, which starts at zero, and
the networks learn their category's mean shape long before they read the sketch (BENCHMARKS.md,
"Why the sketch contributes so little"). This term gives the encoder a direct, supervised signal
instead: a linear head on the code regresses the leading principal components of the target's
distance field, sampled at a fixed grid of anchor points in the unit ball the models are
normalized to. The components come from the training split (one pass before training), are
whitened (unit variance each), and describe exactly the shape differences the category has —
span, length, thickness, parts present — whatever the drawing's viewpoint. Not in the paper.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import Tensor

GRID = 8  # anchors per axis: 512 distance samples per shape
DIMS = 16  # principal components kept


def anchor_grid(n: int = GRID) -> Tensor:
    """``(n³, 3)`` cell centres of an n × n × n grid over [-1, 1]³ (models have radius 1)."""
    c = (torch.arange(n, dtype=torch.float32) + 0.5) / n * 2 - 1
    return torch.stack(torch.meshgrid(c, c, c, indexing="ij"), dim=-1).reshape(-1, 3)


def distance_descriptor(points: Tensor, anchors: Tensor) -> Tensor:
    """``(B, M)``: distance from each anchor to the nearest of a shape's points ``(B, N, 3+)``."""
    xyz = points[..., :3]
    return torch.cdist(anchors.to(xyz).expand(xyz.shape[0], -1, -1), xyz).amin(dim=2)


@dataclasses.dataclass(frozen=True)
class ShapeBasis:
    """Whitened principal components of the training split's distance descriptors."""

    anchors: Tensor  # (M, 3)
    mean: Tensor  # (M,)
    components: Tensor  # (K, M), orthonormal rows
    scale: Tensor  # (K,) standard deviation of the training descriptors along each component

    @property
    def dims(self) -> int:
        return int(self.components.shape[0])

    def coefficients(self, points: Tensor) -> Tensor:
        """``(B, K)`` whitened coordinates of shapes ``(B, N, 3+)`` in the basis (unit variance
        over the training split)."""
        d = distance_descriptor(points, self.anchors) - self.mean.to(points)
        return d @ self.components.to(points).T / self.scale.to(points)

    def state(self) -> dict[str, Tensor]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    @classmethod
    def from_state(cls, state: dict[str, Tensor]) -> "ShapeBasis":
        return cls(**{f.name: state[f.name].float() for f in dataclasses.fields(cls)})


def fit_basis(descriptors: Tensor, anchors: Tensor, dims: int = DIMS) -> ShapeBasis:
    """Principal components of ``(S, M)`` descriptors (one row per training shape); keeps at most
    ``dims`` and never more than the shapes can span."""
    if descriptors.dim() != 2 or descriptors.shape[0] < 2:
        raise ValueError(f"need (S >= 2, M) descriptors, got {tuple(descriptors.shape)}")
    d = descriptors.double()
    mean = d.mean(dim=0)
    _, s, vh = torch.linalg.svd(d - mean, full_matrices=False)
    k = min(dims, int((s > s[0] * 1e-6).sum()))
    scale = s[:k] / (d.shape[0] - 1) ** 0.5
    # sign convention (largest entry positive) so the same descriptors give the same basis
    comps = vh[:k] * torch.sign(vh[:k].gather(1, vh[:k].abs().argmax(dim=1, keepdim=True)))
    return ShapeBasis(anchors.float(), mean.float(), comps.float(), scale.float())


def shape_code_loss(predicted: Tensor, target: Tensor) -> Tensor:
    """Per-item ``(B,)`` mean squared error between predicted and target whitened coefficients."""
    return (predicted - target).pow(2).mean(dim=1)
