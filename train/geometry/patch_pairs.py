"""Which patch pairs a collision test looks at, and what of each pair it leaves out.

Neighbouring patches meet along their shared curves and corners by construction, so a test of
whether they cross must not count those contacts: for each pair that shares a side, part of a
side, a corner or a junction, grid vertices within ``truncate`` rows of what they share are
masked out on both patches. The collision loss and ``evaluate``'s crossing count use the same
pairs, so this sits below both.

With ``seam_contact`` the pairs also name each pair's seam vertices (those on what the two share):
the loss then looks at crossings up to the seam itself but does not count a crossing whose
poking end is a seam vertex, which is where two patches meet rather than cross (a junction that
splits a seam on one side only leaves the two grids' seam vertices apart by a little).
"""

from __future__ import annotations

import dataclasses
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
    # (K, grid*grid) bool: vertices on what pair k shares (``seam_contact``); None: not used
    seam_i: Tensor | None = None
    seam_j: Tensor | None = None

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
            None if self.seam_i is None else self.seam_i.to(device),
            None if self.seam_j is None else self.seam_j.to(device),
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


def _seam_vertices(sides: list[bool], corners: list[bool], grid: int) -> Tensor:
    """The boundary row of each shared side and each shared corner vertex, ``(grid*grid,)`` bool."""
    return ~(_vertex_mask(sides, [False] * 4, grid, 1) & _vertex_mask([False] * 4, corners, grid, 0))


def collision_pairs(
    template: PatchAdjacency, grid: int = 8, truncate: int = 1, seam_contact: bool = False
) -> CollisionPairs:
    """All patch pairs of a ``Template`` with truncation masks for adjacent ones (and, with
    ``seam_contact``, their seam vertices)."""
    n = template.num_patches
    adjacent = set(template.adjacency())
    pairs, keep_i, keep_j, seam_i, seam_j = [], [], [], [], []
    full = torch.ones(grid * grid, dtype=torch.bool)
    for i in range(n):
        for j in range(i + 1, n):
            pairs.append((i, j))
            if (i, j) in adjacent:
                feats_i, feats_j = template.shared_features(i, j), template.shared_features(j, i)
                keep_i.append(_vertex_mask(*feats_i, grid, truncate))
                keep_j.append(_vertex_mask(*feats_j, grid, truncate))
                seam_i.append(_seam_vertices(*feats_i, grid))
                seam_j.append(_seam_vertices(*feats_j, grid))
            else:
                keep_i.append(full)
                keep_j.append(full)
                seam_i.append(~full)
                seam_j.append(~full)
    packed = _pack(pairs, keep_i, keep_j, grid)
    if not seam_contact or not pairs:
        return packed
    return dataclasses.replace(packed, seam_i=torch.stack(seam_i), seam_j=torch.stack(seam_j))


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
