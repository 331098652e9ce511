"""Collision (self-intersection) loss between patches: the penetration depth of crossings.

The paper's L_coll, Σ_{i≠j} exp(−(d(T^i, P^j)/ε)²) over grid vertices P^j and triangles T^i, is
blind to two patches that cross between grid vertices: no vertex is near the other patch, so the
loss and its gradient are 0 (see docs/geometry.md). This term looks at the crossing itself.

Both patches are triangulated on a ``grid``×``grid`` grid. For an ordered pair (i, j), every grid
edge of patch i that passes through a triangle of patch j is a crossing. Its penalty is the
distance to the triangle's plane of the edge end that lies on the *minority* side of patch j,
the side where fewer of patch i's vertices lie (signed distances summed, detached): the gradient
pulls the part of patch i that pokes through back to the side where the rest of it is, and the
pair (j, i) does the same for patch j, so the two separate. Patches that do not cross cost 0.
Pairs that share a curve, part of a curve, a corner or a junction are truncated: grid vertices
within ``truncate`` rows of the shared sides/corners and the edges and triangles touching them
are left out on both patches, so patches that only meet along their common boundary cost 0.

Culling keeps it cheap: patch pairs by bounding box, then (edge, triangle) pairs by bounding box
and by the edge's end points lying on both sides of the triangle's plane, all detached; the
differentiable depth is computed only for the crossings found.

On a GPU the culling is where the training step waits for the device: each list whose length
depends on the shapes is one read-back of its size. They are few and fixed in number: the
candidate pairs (one), their overlapping cells (one per block of candidates: one block on a
GPU), and for both crossing directions at once the edges through a triangle's plane, the unique
edges, the kept ones and the crossings (four). Every index table the term needs is made once
per grid and device.
"""

from __future__ import annotations

import functools

import torch
from torch import Tensor

from train.geometry.patch_pairs import CollisionPairs
from train.geometry.triangulate import grid_faces, triangulate_patches

_TINY = 1e-20


_CELL_EDGES = [[0, 1], [1, 2], [3, 2], [0, 3], [0, 2]]  # a cell's 4 sides and its a–c diagonal, as corner pairs
# candidates per block of the cell-box test: a (chunk, C, C) mask stays in cache on a CPU; a GPU
# takes a batch's candidates in one block (one read-back instead of one per block)
_CHUNK = {"cpu": 256}
_DEVICE_CHUNK = 16384


@functools.lru_cache(maxsize=16)
def _cells(grid: int, device: torch.device) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Per grid cell: its 4 vertex ids ``(C, 4)`` (a, b, c, d counter-clockwise), its 5 edges as
    vertex pairs ``(C, 5, 2)`` (4 sides + the a–c diagonal) and its 2 triangles' face ids ``(C, 2)``
    in ``grid_triangulation(grid)``'s order; then ``_CELL_EDGES`` ``(5, 2)``. Made once per grid
    and device (shared: do not modify)."""
    k = grid - 1
    with torch.inference_mode(False):  # kept for later steps, which autograd records
        i_t, i_s = torch.meshgrid(torch.arange(k), torch.arange(k), indexing="ij")
        a = (i_t * grid + i_s).reshape(-1)
        quad = torch.stack([a, a + 1, a + grid + 1, a + grid], -1)
        edges = quad[:, _CELL_EDGES]
        faces = torch.stack([torch.arange(k * k), torch.arange(k * k) + k * k], -1)
        ends = torch.tensor(_CELL_EDGES)
        return quad.to(device), edges.to(device), faces.to(device), ends.to(device)


def _overlapping_cells(lo: Tensor, hi: Tensor, b: Tensor, i: Tensor, j: Tensor, chunk: int) -> Tensor:
    """(candidate, cell of i, cell of j) rows whose cell boxes overlap, for candidate patch pairs
    ``(b, i, j)`` and per-patch cell boxes ``lo, hi (B, P, C, 3)``. A cell's box is that of its 4
    vertices, which are also its 2 triangles' corners, so one list serves both crossing
    directions (i's edges through j's triangles and j's through i's)."""
    out = []
    lo_t, hi_t = lo.movedim(-1, 0).contiguous(), hi.movedim(-1, 0).contiguous()  # (3, B, P, C)
    for s in range(0, b.shape[0], chunk):
        bb, ii, jj = b[s : s + chunk], i[s : s + chunk], j[s : s + chunk]
        lo_i, lo_j, hi_i, hi_j = (x[:, bb, p] for x in (lo_t, hi_t) for p in (ii, jj))  # (3, n, C)
        over = lo_i[0, :, :, None] <= hi_j[0, :, None]  # (n, C, C), one axis at a time: no (n, C, C, 3)
        over &= lo_j[0, :, None] <= hi_i[0, :, :, None]
        for d in (1, 2):
            over &= lo_i[d, :, :, None] <= hi_j[d, :, None]
            over &= lo_j[d, :, None] <= hi_i[d, :, :, None]
        rows = over.nonzero()
        rows[:, 0] += s
        out.append(rows)
    return torch.cat(out) if out else torch.zeros((0, 3), dtype=torch.long, device=lo.device)


def _crossings(
    verts: Tensor, b: Tensor, src: Tensor, dst: Tensor, keep_src: Tensor, keep_dst: Tensor, cells: Tensor, grid: int
) -> Tensor:
    """(candidate, vertex a, vertex b, triangle) rows where the grid edge a–b of patch ``src`` passes
    through a triangle of patch ``dst`` (detached ``verts (B, P, V, 3)``; candidates ``b, src, dst,
    keep_src (N, V), keep_dst (N, V)``; kept edges and triangles only), from the overlapping cells
    ``(candidate, source cell, target cell)``: the 5 edges of the source cell against the 2
    triangles of the target cell (unique rows)."""
    quad, cell_edges, cell_faces, ends = _cells(grid, verts.device)
    faces = grid_faces(grid, verts.device)
    r, c_src, c_dst = cells.unbind(-1)
    # first the cell's 5 edges against the planes of the 2 target triangles, with the plane test
    # below (same arithmetic): only edges with ends strictly on both sides of a plane go on
    br = b[r]
    t = _at(verts, br[:, None, None], dst[r, None, None], faces[cell_faces[c_dst]])  # (h, 2, 3, 3)
    normal = torch.linalg.cross(t[:, :, 1] - t[:, :, 0], t[:, :, 2] - t[:, :, 0], dim=-1)  # (h, 2, 3)
    corner = _at(verts, br[:, None], src[r, None], quad[c_src])  # (h, 4, 3)
    sd = ((corner[:, None] - t[:, :, None, 0]) * normal[:, :, None]).sum(-1)  # (h, 2, 4)
    row, tri, edge = (sd[:, :, ends[:, 0]] * sd[:, :, ends[:, 1]] < 0).nonzero().unbind(-1)  # (h, 2, 5) → rows
    r, e, f = r[row], cell_edges[c_src[row], edge], cell_faces[c_dst[row], tri]
    n_v, n_f = verts.shape[2], faces.shape[0]
    # an edge borders 2 cells: unique (candidate, a, b, triangle) rows, through one int64 key each
    key = ((r * n_v + e[:, 0]) * n_v + e[:, 1]) * n_f + f
    key = torch.unique(key)
    f, key = key % n_f, key // n_f
    vb, key = key % n_v, key // n_v
    va, r = key % n_v, key // n_v
    ok = keep_src[r, va] & keep_src[r, vb] & keep_dst[r[:, None], faces[f]].all(-1)
    r, va, vb, f = torch.stack([r, va, vb, f], -1)[ok].unbind(-1)  # one read-back, not one per column
    br, sr = b[r], src[r]
    t = _at(verts, br[:, None], dst[r, None], faces[f])  # (h, 3, 3)
    pa, pb = _at(verts, br, sr, va), _at(verts, br, sr, vb)
    normal = torch.linalg.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0], dim=-1)
    da, db = ((pa - t[:, 0]) * normal).sum(-1), ((pb - t[:, 0]) * normal).sum(-1)
    through = da * db < 0  # strictly on both sides of the plane
    # where the edge meets the plane: inside the triangle? (edge functions on the triangle's plane)
    x = pa + (da / torch.where(through, da - db, torch.ones_like(da)))[:, None] * (pb - pa)
    inside = torch.ones_like(through)
    for k in range(3):
        u, v = t[:, k], t[:, (k + 1) % 3]
        inside &= (torch.linalg.cross(v - u, x - u, dim=-1) * normal).sum(-1) >= 0
    hit = through & inside
    return torch.stack([r, va, vb, f], -1)[hit]


def _at(verts: Tensor, b: Tensor, p: Tensor, v: Tensor | None = None) -> Tensor:
    """``verts (B, P, V, 3)`` at batch items ``b``, patches ``p`` and vertices ``v`` (broadcast
    together; every vertex of the patch when ``v`` is None) → ``(..., 3)`` or ``(..., V, 3)``.
    One flat index_select: much cheaper on CPU than advanced indexing with three index tensors."""
    n_p, n_v = verts.shape[1], verts.shape[2]
    if v is None:
        v, b, p = torch.arange(n_v, device=verts.device), b[..., None], p[..., None]
    idx = (b * n_p + p) * n_v + v
    return verts.reshape(-1, 3).index_select(0, idx.reshape(-1)).reshape(*idx.shape, 3)


def _kept_box(v: Tensor, keep: Tensor) -> tuple[Tensor, Tensor]:
    """Bounding box ``(N, 3)`` of the kept vertices ``keep (N, V)`` of ``v (N, V, 3)``."""
    k = keep[..., None]
    return torch.where(k, v, torch.full_like(v, float("inf"))).amin(-2), torch.where(
        k, v, torch.full_like(v, -float("inf"))
    ).amax(-2)


def _candidates(v: Tensor, pairs: CollisionPairs, patch_mask: Tensor | None) -> tuple[Tensor, Tensor]:
    """(batch item, pair) of the pairs that may cross, for detached ``v (B, P, V, 3)``: both
    patches present and their boxes overlapping, where for pairs sharing a boundary the boxes
    are those of the kept vertices only (the bands along what they share left out). Every test
    runs on the whole ``(B, K)`` table (the kept boxes on every item's boundary-sharing pairs),
    so the list is one read-back."""
    pr, keep_i, keep_j = pairs.pairs, pairs.keep_i, pairs.keep_j
    lo, hi = v.amin(2), v.amax(2)  # (B, P, 3)
    lo_i, hi_i, lo_j, hi_j = lo[:, pr[:, 0]], hi[:, pr[:, 0]], lo[:, pr[:, 1]], hi[:, pr[:, 1]]  # (B, K, 3)
    near = ((lo_i <= hi_j) & (lo_j <= hi_i)).all(-1)  # (B, K)
    if patch_mask is not None:
        pm = patch_mask.to(v.device)
        near &= pm[:, pr[:, 0]] & pm[:, pr[:, 1]]
    part = pairs.partial_pairs()
    if part.numel():
        for lo_x, hi_x, col, keep in ((lo_i, hi_i, 0, keep_i), (lo_j, hi_j, 1, keep_j)):
            k_lo, k_hi = _kept_box(v.index_select(1, pr[part, col]), keep[part][None])  # (B, K', 3)
            lo_x.index_copy_(1, part, k_lo)
            hi_x.index_copy_(1, part, k_hi)
    kept = near & ((lo_i <= hi_j) & (lo_j <= hi_i)).all(-1)
    return kept.nonzero().unbind(-1)


def collision_loss(
    patches: Tensor, pairs: CollisionPairs, chunk: int | None = None, patch_mask: Tensor | None = None
) -> Tensor:
    """Penetration depth per batch item ``(B,)`` for ``patches (B, P, 4, 4, 3)``: the sum over
    crossings of both ordered pairs (i, j), (j, i). ``patch_mask (B, P)`` leaves out pairs with an
    absent patch (optional parts). ``chunk``: candidates per block of the cell-box test (default
    256 on a CPU, a batch's worth elsewhere; the result does not depend on it)."""
    # zero that stays attached to the graph, so backward works when nothing crosses
    out = (patches * 0).flatten(1).sum(-1)
    if pairs.pairs.numel() == 0:
        return out
    dev = patches.device
    verts, faces = triangulate_patches(patches, pairs.grid)  # (B, P, V, 3), (F, 3)
    verts = verts.contiguous()  # gathered from often below, through a flat view
    on = pairs.to(dev)  # no copy when they are there already (the objective keeps them on its device)
    keep_i, keep_j = on.keep_i, on.keep_j
    with torch.no_grad():
        v = verts.detach()
        b, k = _candidates(v, on, patch_mask)
        pi, pj = on.pairs[k, 0], on.pairs[k, 1]
        n = b.shape[0]
        quad = _cells(pairs.grid, dev)[0]
        cell_v = v[:, :, quad]  # (B, P, C, 4, 3)
        cells = _overlapping_cells(
            cell_v.amin(-2), cell_v.amax(-2), b, pi, pj, chunk or _CHUNK.get(dev.type, _DEVICE_CHUNK)
        )
        # both directions in one pass: candidate rows 0..n-1 are i's edges through j's triangles,
        # n..2n-1 j's through i's (the same cell pairs, columns swapped)
        b2, src, dst = torch.cat([b, b]), torch.cat([pi, pj]), torch.cat([pj, pi])
        k_src, k_dst = torch.cat([keep_i[k], keep_j[k]]), torch.cat([keep_j[k], keep_i[k]])
        swapped = torch.stack([cells[:, 0] + n, cells[:, 2], cells[:, 1]], -1)
        hit = _crossings(v, b2, src, dst, k_src, k_dst, torch.cat([cells, swapped]), pairs.grid)
    if hit.shape[0] == 0:
        return out
    r, va, vb, f = hit.unbind(-1)
    br, sr = b2[r], src[r]
    t = _at(verts, br[:, None], dst[r, None], faces[f])  # (h, 3, 3)
    normal = torch.linalg.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0], dim=-1)
    unit = normal / normal.norm(dim=-1, keepdim=True).clamp_min(_TINY)
    ends = _at(verts, br[:, None], sr[:, None], torch.stack([va, vb], 1))  # (h, 2, 3)
    signed = ((ends - t[:, None, 0]) * unit[:, None]).sum(-1)  # (h, 2)
    with torch.no_grad():  # which side of the triangle most of patch `src` lies on
        all_sd = ((_at(v, br, sr) - t[:, None, 0].detach()) * unit[:, None].detach()).sum(-1)
        side = torch.sign((all_sd * k_src[r].to(all_sd.dtype)).sum(-1))
        side = torch.where(side == 0, torch.ones_like(side), side)
        minority = (signed.detach() * side[:, None] < 0).to(signed.dtype)  # one end per crossing
    # rows come sorted by candidate row, the i→j direction first: summed in the order of two
    # passes, one per direction
    depth = patches.new_zeros(n).index_add(0, torch.where(r < n, r, r - n), (signed.abs() * minority).sum(-1))
    return out.index_add(0, b, depth)
