"""Surface samples of a union of boxes: what a cuboid file's model looks like to the median.

A cuboid file has no mesh, so the Chamfer distances behind the median model are taken between
samples of each model's box union (points on a box face that lie inside another box are not on
the union's surface and are rejected).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from train.templates.authoring.lattice import CuboidLike


def box_union_samples(boxes: Sequence[CuboidLike], n: int, rng: np.random.Generator) -> np.ndarray:
    """About ``n`` points (n, 3) on the surface of the union of ``boxes``, area-uniform."""
    lo = np.array([np.asarray(b.lo, float) for b in boxes])
    hi = np.array([np.asarray(b.hi, float) for b in boxes])
    size = hi - lo
    # one face pair per axis: area = product of the other two extents
    areas = np.stack([size[:, 1] * size[:, 2], size[:, 2] * size[:, 0], size[:, 0] * size[:, 1]], 1)
    total = 2 * areas.sum()
    if not total > 0:
        raise ValueError("the boxes have no surface")
    out: list[np.ndarray] = []
    got, tries = 0, 0
    eps = 1e-9 * float(np.abs(hi).max() + np.abs(lo).max() + 1)
    while got < n and tries < 20:  # rejection can remove most points of a heavily overlapping set
        tries += 1
        m = 2 * (n - got) + 16
        flat = np.repeat(areas.reshape(-1), 2) / total
        pick = rng.choice(len(flat), size=m, p=flat / flat.sum())
        box, axis, side = pick // 6, (pick // 2) % 3, pick % 2
        p = lo[box] + rng.random((m, 3)) * size[box]
        p[np.arange(m), axis] = np.where(side == 1, hi[box, axis], lo[box, axis])
        inside = np.zeros(m, bool)
        for k in range(len(boxes)):
            strictly = np.all((p > lo[k] + eps) & (p < hi[k] - eps), axis=1)
            inside |= strictly & (box != k)
        keep = p[~inside]
        out.append(keep)
        got += len(keep)
    pts = np.concatenate(out)[:n]
    if len(pts) == 0:
        raise ValueError("no point of the boxes lies on their union's surface")
    return pts
