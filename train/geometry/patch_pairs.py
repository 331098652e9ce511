"""Which patch pairs a collision test looks at, and what of each pair it leaves out.

Neighbouring patches meet along their shared curves and corners by construction, so a test of
whether they cross must not count those contacts: for each pair that shares a side, part of a
side, a corner or a junction, grid vertices within ``truncate`` rows of what they share are
masked out on both patches. The collision loss and ``evaluate``'s crossing count use the same
pairs, so this sits below both.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import torch
from torch import Tensor


class PatchAdjacency(Protocol):
    """What the pairs need of a template: ``Template`` provides it."""

    num_patches: int

    def adjacency(self) -> list[tuple[int, int]]: ...

    def shared_features(self, i: int, j: int) -> tuple[list[bool], list[bool]]: ...


@dataclass(frozen=True)
class CollisionPairs:
    """Patch pairs (i < j) and per-pair vertex masks (True = kept) on a ``grid``×``grid`` grid."""

    pairs: Tensor  # (K, 2) long
    keep_i: Tensor  # (K, grid*grid) bool, vertices of patch i kept for pair k
    keep_j: Tensor  # (K, grid*grid) bool
    grid: int
    # (K',) long: the pairs whose masks leave vertices out (those sharing a boundary); None: not
    # listed yet (``partial_pairs`` finds them). Built with the masks, so a training step need not.
    partial: Tensor | None = field(default=None, compare=False)

    def partial_pairs(self) -> Tensor:
        """Indices of the pairs whose masks leave vertices out, ``(K',)`` long."""
        if self.partial is not None:
            return self.partial
        return (~(self.keep_i.all(-1) & self.keep_j.all(-1))).nonzero().squeeze(1)

    def to(self, device: torch.device) -> "CollisionPairs":
        """These pairs with every tensor on ``device``."""
        return CollisionPairs(
            self.pairs.to(device),
            self.keep_i.to(device),
            self.keep_j.to(device),
            self.grid,
            self.partial_pairs().to(device),
        )


def _vertex_mask(sides: list[bool], corners: list[bool], grid: int, truncate: int) -> Tensor:
    ax = torch.arange(grid)
    i_t, i_s = torch.meshgrid(ax, ax, indexing="ij")
    lo_s, hi_s = i_s < truncate, i_s > grid - 1 - truncate
    lo_t, hi_t = i_t < truncate, i_t > grid - 1 - truncate
    band = truncate + 1  # corner contacts: a slightly larger square around the corner
    near = [
        (i_s < band) & (i_t < band),
        (i_s > grid - 1 - band) & (i_t < band),
        (i_s > grid - 1 - band) & (i_t > grid - 1 - band),
        (i_s < band) & (i_t > grid - 1 - band),
    ]
    drop = torch.zeros(grid, grid, dtype=torch.bool)
    for flag, region in zip(sides, (lo_t, hi_s, hi_t, lo_s)):  # c1 bottom, c2 right, c3 top, c4 left
        if flag:
            drop |= region
    for flag, region in zip(corners, near):  # P00, P10, P11, P01
        if flag:
            drop |= region
    return ~drop.reshape(-1)


def collision_pairs(template: PatchAdjacency, grid: int = 8, truncate: int = 1) -> CollisionPairs:
    """All patch pairs of a ``Template`` with truncation masks for adjacent ones."""
    n = template.num_patches
    adjacent = set(template.adjacency())
    pairs, keep_i, keep_j = [], [], []
    full = torch.ones(grid * grid, dtype=torch.bool)
    for i in range(n):
        for j in range(i + 1, n):
            pairs.append((i, j))
            if (i, j) in adjacent:
                keep_i.append(_vertex_mask(*template.shared_features(i, j), grid, truncate))
                keep_j.append(_vertex_mask(*template.shared_features(j, i), grid, truncate))
            else:
                keep_i.append(full)
                keep_j.append(full)
    return _pack(pairs, keep_i, keep_j, grid)


def unconnected_pairs(num_patches: int, grid: int = 8) -> CollisionPairs:
    """Every pair without truncation (patches known not to touch, e.g. a test of loose patches)."""
    pairs = [(i, j) for i in range(num_patches) for j in range(i + 1, num_patches)]
    full = [torch.ones(grid * grid, dtype=torch.bool)] * len(pairs)
    return _pack(pairs, full, full, grid)


def _pack(pairs, keep_i, keep_j, grid) -> CollisionPairs:
    if not pairs:
        empty = torch.zeros((0, grid * grid), dtype=torch.bool)
        return CollisionPairs(
            torch.zeros((0, 2), dtype=torch.long), empty, empty, grid, torch.zeros(0, dtype=torch.long)
        )
    packed = CollisionPairs(torch.tensor(pairs, dtype=torch.long), torch.stack(keep_i), torch.stack(keep_j), grid)
    return CollisionPairs(packed.pairs, packed.keep_i, packed.keep_j, grid, packed.partial_pairs())
