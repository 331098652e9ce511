"""Collision (self-intersection) loss between patches, the paper's L_coll:

    Σ_{i≠j} exp(−(min(d(T^i, P^j), d(T^j, P^i)) / ε)²)

with T^i a fixed-grid triangulation of patch i and P^j its grid vertices. d is the smallest
*squared* point–triangle distance (so ε = 1e-6 means contact within ~1e-3 on unit-sphere
models). Pairs that share a curve, part of a curve, a corner or a junction are truncated: grid
vertices within ``truncate`` rows of the shared sides/corners and the triangles touching them
are left out on both patches. Pairs whose bounding boxes are farther apart than the indicator can
see are culled before any distance is computed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from train.geometry.triangulate import triangulate_patches

_TINY = 1e-20


@dataclass(frozen=True)
class CollisionPairs:
    """Patch pairs (i < j) and per-pair vertex masks (True = kept) on a ``grid``×``grid`` grid."""

    pairs: Tensor  # (K, 2) long
    keep_i: Tensor  # (K, grid*grid) bool, vertices of patch i kept for pair k
    keep_j: Tensor  # (K, grid*grid) bool
    grid: int


def _vertex_mask(sides: list[bool], corners: list[bool], grid: int, truncate: int) -> Tensor:
    ax = torch.arange(grid)
    i_t, i_s = torch.meshgrid(ax, ax, indexing="ij")
    lo_s, hi_s = i_s < truncate, i_s > grid - 1 - truncate
    lo_t, hi_t = i_t < truncate, i_t > grid - 1 - truncate
    band = truncate + 1  # corner contacts: a slightly larger square around the corner
    near = [(i_s < band) & (i_t < band), (i_s > grid - 1 - band) & (i_t < band),
            (i_s > grid - 1 - band) & (i_t > grid - 1 - band), (i_s < band) & (i_t > grid - 1 - band)]
    drop = torch.zeros(grid, grid, dtype=torch.bool)
    for flag, region in zip(sides, (lo_t, hi_s, hi_t, lo_s)):  # c1 bottom, c2 right, c3 top, c4 left
        if flag:
            drop |= region
    for flag, region in zip(corners, near):  # P00, P10, P11, P01
        if flag:
            drop |= region
    return ~drop.reshape(-1)


def collision_pairs(template, grid: int = 8, truncate: int = 1) -> CollisionPairs:
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
        return CollisionPairs(torch.zeros((0, 2), dtype=torch.long), empty, empty, grid)
    return CollisionPairs(torch.tensor(pairs, dtype=torch.long), torch.stack(keep_i), torch.stack(keep_j), grid)


def _seg_sqdist(p: Tensor, a: Tensor, b: Tensor) -> Tensor:
    ab = b - a
    t = (((p - a) * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(_TINY)).clamp(0.0, 1.0)
    return ((p - a - t[..., None] * ab) ** 2).sum(-1)


def point_triangle_sqdist(p: Tensor, a: Tensor, b: Tensor, c: Tensor) -> Tensor:
    """Squared distance from points to triangles (all broadcastable ``(..., 3)``) → ``(...)``."""
    ab, ac, ap = b - a, c - a, p - a
    d00, d01, d11 = (ab * ab).sum(-1), (ab * ac).sum(-1), (ac * ac).sum(-1)
    d20, d21 = (ap * ab).sum(-1), (ap * ac).sum(-1)
    denom = d00 * d11 - d01 * d01  # = |ab × ac|²
    safe = denom.clamp_min(_TINY)
    v = (d11 * d20 - d01 * d21) / safe
    w = (d00 * d21 - d01 * d20) / safe
    inside = (v >= 0) & (w >= 0) & (v + w <= 1) & (denom > _TINY)
    n = torch.linalg.cross(ab, ac, dim=-1)
    plane = (ap * n).sum(-1) ** 2 / safe
    edges = torch.minimum(torch.minimum(_seg_sqdist(p, a, b), _seg_sqdist(p, b, c)), _seg_sqdist(p, c, a))
    return torch.where(inside, plane, edges)


def _contacts(points: Tensor, keep_pts: Tensor, tris: Tensor, keep_tris: Tensor, margin: float) -> Tensor:
    """(pair, vertex, triangle) triples whose point lies in the triangle's box grown by ``margin``.

    Detached and boolean only: the exact distance is then computed for these few triples.
    """
    lo, hi = tris.amin(-2) - margin, tris.amax(-2) + margin  # (n, F, 3)
    p = points[:, :, None]
    inside = ((p >= lo[:, None]) & (p <= hi[:, None])).all(-1)  # (n, V, F)
    inside &= keep_pts[:, :, None] & keep_tris[:, None, :]
    return inside.nonzero()


def collision_loss(
    patches: Tensor, pairs: CollisionPairs, eps: float = 1e-6, chunk: int = 256, patch_mask: Tensor | None = None
) -> Tensor:
    """L_coll per batch item ``(B,)`` for ``patches (B, P, 4, 4, 3)``; ordered pairs (i≠j) count twice.
    ``patch_mask (B, P)`` leaves out pairs with an absent patch (optional parts).

    Culling: patch pairs by bounding box, then point/triangle pairs by triangle box, both grown
    by the distance beyond which exp(−(d/ε)²) < 1e-12; exact distances only for what is left.
    """
    # zero that stays attached to the graph, so backward works when nothing touches
    out = (patches * 0).flatten(1).sum(-1)
    if pairs.pairs.numel() == 0:
        return out
    dev = patches.device
    margin = math.sqrt(6.0 * eps)
    verts, faces = triangulate_patches(patches, pairs.grid)  # (B, P, V, 3), (F, 3)
    pr = pairs.pairs.to(dev)
    keep_i, keep_j = pairs.keep_i.to(dev), pairs.keep_j.to(dev)
    with torch.no_grad():
        lo, hi = verts.amin(2), verts.amax(2)  # (B, P, 3)
        gap = (torch.maximum(lo[:, pr[:, 0]], lo[:, pr[:, 1]]) - torch.minimum(hi[:, pr[:, 0]], hi[:, pr[:, 1]])).clamp_min(0)
        near = (gap * gap).sum(-1) <= margin * margin  # (B, K)
        if patch_mask is not None:
            pm = patch_mask.to(dev)
            near &= pm[:, pr[:, 0]] & pm[:, pr[:, 1]]
        cand = near.nonzero()  # (N, 2): batch, pair
    best = patches.new_zeros(cand.shape[0])
    for start in range(0, cand.shape[0], chunk):
        b, k = cand[start : start + chunk].unbind(-1)
        sl = torch.arange(start, start + b.shape[0], device=dev)
        for src, dst, k_src, k_dst in ((pr[k, 1], pr[k, 0], keep_j[k], keep_i[k]), (pr[k, 0], pr[k, 1], keep_i[k], keep_j[k])):
            pts, tris = verts[b, src], verts[b, dst][:, faces]  # (n, V, 3), (n, F, 3, 3)
            with torch.no_grad():
                hit = _contacts(pts.detach(), k_src, tris.detach(), k_dst[:, faces].all(-1), margin)
            if hit.shape[0] == 0:
                continue
            n, v, f = hit.unbind(-1)
            tri = tris[n, f]
            d = point_triangle_sqdist(pts[n, v], tri[:, 0], tri[:, 1], tri[:, 2])
            term = torch.exp(-((d / eps) ** 2))
            # max over contacts of exp(−(d/ε)²) = exp of the min distance
            best = best.scatter_reduce(0, sl[n], term, reduce="amax", include_self=True)
    return out.index_add(0, cand[:, 0], 2.0 * best)
