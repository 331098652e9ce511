"""Exact 3-D nearest neighbours with a hashed uniform grid, compiled with numba.

Reference points are sorted into buckets by a hash of their cell ``floor(p / h)`` (a table about
four times the occupied cells, no keys: two cells sharing a bucket only add candidates, every
distance is computed exactly). Far-away points — masked samples moved to 1e6, part groups
shifted 100 apart — therefore cost nothing and do not coarsen the grid.

A query first takes a candidate (the previous query's answer: queries are taken cell by cell,
so it is a near point) and scans its own cell; every point at least as near then lies in the box
of cells around the ball of that radius, which it scans, skipping cells whose box is farther
than the best so far. Without a candidate, or when that box exceeds ``_BUDGET`` cells, it
searches cubic shells of cells until the best distance is within the searched cube (every
unsearched point lies beyond one of its faces). A query still open after ``_BUDGET`` cell
visits (far from every reference point, where a grid visits mostly empty cells) is answered by a
k-d tree over the item instead, built only when needed.

Ties: the lowest reference index among equal float64 squared distances (Σ over x, y, z of the
squared difference). For the k-d tree's far queries: the lowest index among coincident
reference points (duplicates), the tree's pick among distinct equidistant ones. Results equal a
k-d tree's wherever the nearest point is unique.

Cell size: grown or shrunk from a bounding-box estimate until the reference points average
about ``_OCCUPANCY`` per occupied bucket (surface samples fill cells unevenly, so this is
measured, not computed from the box volume).

Cost: a query pays for the points of the cells its candidate ball touches, so the grid gains
most when the two clouds are close. On training's matching at the start (airplane template
outputs + noise vs real targets, median distance 0.045, batch 8, ~7,000 points each way) it is
about 1.5× cheaper than a k-d tree per item; with the clouds on each other (late training)
about 2.6× (``bench/bench_matching.py [--on-target]``).

The first call compiles (about 8 s); ``cache=True`` keeps the machine code in numba's cache
(``__pycache__`` beside this file, else a user-wide cache folder or ``NUMBA_CACHE_DIR``), so later
processes (DDP ranks; matching runs in the main process, not in loader workers) load it (~0.5 s)
instead of compiling.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

_OCCUPANCY = 16.0  # target mean points per occupied bucket
_BUDGET = 729  # cells (a 9³ box, or shells) a query may visit before the k-d tree answers it


@numba.njit(cache=True, inline="always")
def _cell_bucket(cx: int, cy: int, cz: int, mask: int) -> int:
    return ((cx * 73856093) ^ (cy * 19349663) ^ (cz * 83492791)) & mask


@numba.njit(cache=True, inline="always")
def _bucket(x: float, y: float, z: float, h: float, mask: int) -> int:
    return _cell_bucket(np.int64(np.floor(x / h)), np.int64(np.floor(y / h)), np.int64(np.floor(z / h)), mask)


@numba.njit(cache=True)
def _build(points, h, count, bucket_of, mask):
    """Count the points of each bucket (first ``mask + 1``); returns how many are occupied."""
    count[: mask + 1] = 0
    occupied = 0
    for i in range(points.shape[0]):
        s = _bucket(points[i, 0], points[i, 1], points[i, 2], h, mask)
        bucket_of[i] = s
        occupied += count[s] == 0
        count[s] += 1
    return occupied


@numba.njit(cache=True)
def _cell_size(ref, count, bucket_of):
    """Cell size giving about ``_OCCUPANCY`` points per occupied bucket, and that count."""
    m = ref.shape[0]
    mask = count.shape[0] - 1
    lo = np.array([ref[:, 0].min(), ref[:, 1].min(), ref[:, 2].min()])
    hi = np.array([ref[:, 0].max(), ref[:, 1].max(), ref[:, 2].max()])
    ext = max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2])
    span = max(abs(lo[0]), abs(lo[1]), abs(lo[2]), abs(hi[0]), abs(hi[1]), abs(hi[2]))
    if ext <= 0.0:
        ext = max(span, 1.0)
    h_min = span * 1e-12  # duplicates cannot be split: stop shrinking somewhere
    h = ext * np.sqrt(_OCCUPANCY / m)
    occ = _build(ref, h, count, bucket_of, mask)
    for _ in range(40):
        ratio = m / occ
        if ratio > 1.5 * _OCCUPANCY and h > h_min:
            new_h = max(h * min(max(np.sqrt(_OCCUPANCY / ratio), 1.0 / 64.0), 0.8), h_min)
        elif ratio < _OCCUPANCY / 3.0 and occ > 1:
            new_h = h * min((_OCCUPANCY / ratio) ** (1.0 / 3.0), 4.0)
        else:
            break
        h, occ = new_h, _build(ref, new_h, count, bucket_of, mask)
    return h, occ


@numba.njit(cache=True, inline="always")
def _scan(q0, q1, q2, lo, hi, pts, order, best, best_i, best_k):
    for j in range(lo, hi):
        d0 = q0 - pts[j, 0]
        d1 = q1 - pts[j, 1]
        d2 = q2 - pts[j, 2]
        d = d0 * d0 + d1 * d1 + d2 * d2
        if d < best or (d == best and order[j] < best_i):
            best, best_i, best_k = d, order[j], j
    return best, best_i, best_k


@numba.njit(cache=True)
def _query_one(q0, q1, q2, h, start, count, pts, order, mask, budget, guess):
    """Position in ``pts`` of the nearest point, or -1 past the budget. ``guess``: a position to
    start from (any point: a near one bounds the search), or -1."""
    # Margin for cell bounds: a point's cell comes from a rounded division.
    eps = 1e-12 * (abs(q0) + abs(q1) + abs(q2) + h) + 1e-300
    best, best_i, best_k = np.inf, np.int64(-1), np.int64(-1)
    if guess >= 0:
        d0, d1, d2 = q0 - pts[guess, 0], q1 - pts[guess, 1], q2 - pts[guess, 2]
        best, best_i, best_k = d0 * d0 + d1 * d1 + d2 * d2, order[guess], guess
    s = _bucket(q0, q1, q2, h, mask)
    best, best_i, best_k = _scan(q0, q1, q2, start[s], start[s] + count[s], pts, order, best, best_i, best_k)
    cx, cy, cz = np.int64(np.floor(q0 / h)), np.int64(np.floor(q1 / h)), np.int64(np.floor(q2 / h))
    r = 0
    if best < np.inf:
        # Every point within the best distance lies in the box of cells around that ball.
        rho = np.sqrt(best) + eps
        x0, x1 = np.int64(np.floor((q0 - rho) / h)), np.int64(np.floor((q0 + rho) / h))
        y0, y1 = np.int64(np.floor((q1 - rho) / h)), np.int64(np.floor((q1 + rho) / h))
        z0, z1 = np.int64(np.floor((q2 - rho) / h)), np.int64(np.floor((q2 + rho) / h))
        nx, ny, nz = x1 - x0 + 1, y1 - y0 + 1, z1 - z0 + 1
        if nx <= budget and ny <= budget and nz <= budget and nx * ny * nz <= budget:  # no overflow
            for x in range(x0, x1 + 1):
                gx = max(x * h - q0, q0 - (x + 1) * h, eps) - eps
                for y in range(y0, y1 + 1):
                    gy = max(y * h - q1, q1 - (y + 1) * h, eps) - eps
                    for z in range(z0, z1 + 1):
                        gz = max(z * h - q2, q2 - (z + 1) * h, eps) - eps
                        # the cell's box is farther than the best so far: skip it
                        if gx * gx + gy * gy + gz * gz > best or (x == cx and y == cy and z == cz):
                            continue
                        s = _cell_bucket(x, y, z, mask)
                        best, best_i, best_k = _scan(
                            q0, q1, q2, start[s], start[s] + count[s], pts, order, best, best_i, best_k
                        )
            return best_k
    # No near candidate: cubic shells of cells around the query's cell until the best distance
    # is within the searched cube (every unsearched point lies beyond one of its faces).
    visits = 0
    while True:
        r += 1
        for dx in range(-r, r + 1):
            for dy in range(-r, r + 1):
                edge = dx == -r or dx == r or dy == -r or dy == r
                step = 1 if edge else 2 * r  # inside the cube's side walls only its caps are new
                dz = -r
                while dz <= r:
                    x, y, z = cx + dx, cy + dy, cz + dz
                    dz += step
                    visits += 1
                    gx = max(x * h - q0, q0 - (x + 1) * h, eps) - eps
                    gy = max(y * h - q1, q1 - (y + 1) * h, eps) - eps
                    gz = max(z * h - q2, q2 - (z + 1) * h, eps) - eps
                    if gx * gx + gy * gy + gz * gz > best:
                        continue
                    s = _cell_bucket(x, y, z, mask)
                    best, best_i, best_k = _scan(
                        q0, q1, q2, start[s], start[s] + count[s], pts, order, best, best_i, best_k
                    )
        face = (
            min(
                q0 - (cx - r) * h,
                (cx + r + 1) * h - q0,
                q1 - (cy - r) * h,
                (cy + r + 1) * h - q1,
                q2 - (cz - r) * h,
                (cz + r + 1) * h - q2,
            )
            - eps
        )
        if face > 0.0 and best <= face * face:
            return best_k
        if visits > budget:
            return -1  # far from every reference point: left to the k-d tree


@numba.njit(cache=True)
def _pow2(n):
    p = 1
    while p < n:
        p *= 2
    return p


@numba.njit(cache=True)
def _sort_by_bucket(bucket_of, count, n_buckets, start, order):
    """``order``: point indices sorted by bucket (stable: index order inside one); ``start[s]``:
    where bucket ``s`` begins in it."""
    total = 0
    for s in range(n_buckets):
        start[s] = total
        total += count[s]
    for i in range(bucket_of.shape[0]):
        order[start[bucket_of[i]]] = i
        start[bucket_of[i]] += 1
    for s in range(n_buckets):
        start[s] -= count[s]


@numba.njit(cache=True)
def _nearest_batch(query, reference, out, first_copy):
    b_count, m = reference.shape[0], reference.shape[1]
    size = _pow2(4 * m)
    start = np.empty(size, np.int64)
    count = np.empty(size, np.int64)
    bucket_of = np.empty(m, np.int64)
    pts = np.empty((m, 3), np.float64)
    order = np.empty(m, np.int64)
    nq = query.shape[1]
    qsize = _pow2(2 * nq)
    qcount = np.empty(qsize, np.int64)
    qstart = np.empty(qsize, np.int64)
    qbucket = np.empty(nq, np.int64)
    qorder = np.empty(nq, np.int64)
    for b in range(b_count):
        ref = reference[b]
        h, occ = _cell_size(ref, count, bucket_of)
        tsize = min(_pow2(4 * occ), size)  # a small table stays in cache
        _build(ref, h, count, bucket_of, tsize - 1)
        _sort_by_bucket(bucket_of, count, tsize, start, order)
        for k in range(m):
            pts[k, 0], pts[k, 1], pts[k, 2] = ref[order[k], 0], ref[order[k], 1], ref[order[k], 2]
        for s in range(tsize):  # lowest index of each point's exact duplicates (same bucket)
            for k in range(start[s], start[s] + count[s]):
                first_copy[b, order[k]] = order[k]
                for k2 in range(start[s], k):
                    if pts[k2, 0] == pts[k, 0] and pts[k2, 1] == pts[k, 1] and pts[k2, 2] == pts[k, 2]:
                        first_copy[b, order[k]] = order[k2]
                        break
        # Queries grouped by cell: each starts from its predecessor's answer, a near point.
        _build(query[b], h, qcount, qbucket, qsize - 1)
        _sort_by_bucket(qbucket, qcount, qsize, qstart, qorder)
        guess = np.int64(-1)
        for i in qorder:
            k = _query_one(
                query[b, i, 0], query[b, i, 1], query[b, i, 2], h, start, count, pts, order, tsize - 1, _BUDGET, guess
            )
            out[b, i] = order[k] if k >= 0 else -1
            if k >= 0:
                guess = k


def grid_nearest(query: np.ndarray, reference: np.ndarray) -> np.ndarray | None:
    """Index of the nearest ``reference`` point for each ``query`` point, exact.

    ``query (B, N, 3)``, ``reference (B, M, 3)`` float64 → ``(B, N)`` int64, ties to the lowest
    index (see the module doc for far queries). ``None`` where the grid does not apply (empty
    sets, non-finite or huge coordinates); the caller then uses a k-d tree alone.
    """
    if reference.shape[1] == 0 or query.shape[1] == 0:
        return None
    q = np.ascontiguousarray(query, dtype=np.float64)
    r = np.ascontiguousarray(reference, dtype=np.float64)
    # Cell indices and face distances stay well inside int64 / float64 precision below this.
    span = max(np.abs(q).max(), np.abs(r).max())
    if not (np.isfinite(span) and span < 1e9):
        return None
    out = np.empty(q.shape[:2], dtype=np.int64)
    first_copy = np.empty(r.shape[:2], dtype=np.int64)
    _nearest_batch(q, r, out, first_copy)
    for b in np.flatnonzero((out < 0).any(axis=1)):
        far = out[b] < 0
        tree = cKDTree(r[b], balanced_tree=False, compact_nodes=False)  # quicker to build
        out[b, far] = first_copy[b, tree.query(q[b, far], k=1, workers=1)[1]]
    return out
