"""Mirror symmetry of a cuboid collection across the plane x = 0 (the normalized frame).

Models are normalized with their bounding-box centre at the origin, so a left/right symmetric
model's plane is x = 0. Every box either has a partner of the same label whose mirror image it
nearly is, or is itself nearly symmetric (centred on the plane); then the collection is symmetric,
and ``symmetrize`` makes it exactly so (each pair averaged), so the symmetric template
construction does not double boxes that are off by a few hundredths.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from train.templates.authoring.lattice import Box

MIRROR_TOL = 0.03  # normalized units (radius 1): how far a box may sit from its partner's mirror image


@dataclass(frozen=True)
class MirrorReport:
    pairs: tuple[tuple[int, int], ...]  # box indices that mirror each other
    self_symmetric: tuple[int, ...]  # boxes centred on the plane
    unpaired: tuple[int, ...]  # boxes with no mirror image: the collection is not symmetric

    @property
    def symmetric(self) -> bool:
        return not self.unpaired


def _mirror(b: Box) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.array(b.lo, float), np.array(b.hi, float)
    lo[0], hi[0] = -b.hi[0], -b.lo[0]
    return lo, hi


def _gap(a: Box, b: Box) -> float:
    """Largest coordinate difference between box ``a`` and the mirror image of ``b``."""
    lo, hi = _mirror(b)
    return float(max(np.abs(np.asarray(a.lo) - lo).max(), np.abs(np.asarray(a.hi) - hi).max()))


def mirror_pairs(boxes: Sequence[Box], tol: float = MIRROR_TOL) -> MirrorReport:
    """Pair boxes greedily, closest mirror images first, within ``tol``; same label only."""
    n = len(boxes)
    self_sym = [i for i in range(n) if _gap(boxes[i], boxes[i]) <= tol]
    cand = sorted(
        (_gap(boxes[i], boxes[j]), i, j)
        for i in range(n)
        for j in range(i + 1, n)
        if boxes[i].label == boxes[j].label and i not in self_sym and j not in self_sym
    )
    used: set[int] = set(self_sym)
    pairs = []
    for g, i, j in cand:
        if g <= tol and i not in used and j not in used:
            pairs.append((i, j))
            used.update((i, j))
    return MirrorReport(tuple(pairs), tuple(self_sym), tuple(i for i in range(n) if i not in used))


def symmetrize(boxes: Sequence[Box], report: MirrorReport) -> list[Box]:
    """Exactly symmetric boxes: pairs averaged with each other's mirror image, self-symmetric
    boxes centred on x = 0; unpaired boxes are kept as they are."""
    out = [Box(b.label, np.array(b.lo, float), np.array(b.hi, float)) for b in boxes]
    for i, j in report.pairs:
        lo_j, hi_j = _mirror(boxes[j])
        lo, hi = (out[i].lo + lo_j) / 2, (out[i].hi + hi_j) / 2
        out[i] = Box(boxes[i].label, lo, hi)
        out[j] = Box(boxes[j].label, *_mirror(out[i]))
    for i in report.self_symmetric:
        half = (out[i].hi[0] - out[i].lo[0]) / 2
        lo, hi = out[i].lo.copy(), out[i].hi.copy()
        lo[0], hi[0] = -half, half
        out[i] = Box(boxes[i].label, lo, hi)
    return out
