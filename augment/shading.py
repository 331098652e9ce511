"""Soft tone beside contours: the light, broad strokes a person shades a drawing with.

A person's pencil sketch is rarely clean lines only: the paper's released demo sketches are
lighter and broader than line drawings, with tone laid along the contours. ``tone_strokes``
gives a share of the strokes one or two companions shifted sideways along their normal (one side
per stroke, as shading sits on the shadow side of an edge), each covering a random stretch of
it; the rasterizer draws them lighter and broader than the lines.
"""

from __future__ import annotations

import numba
import numpy as np

from augment.strokes import flat_strokes, split_strokes

MIN_LENGTH = 6.0  # output px: shorter strokes (ticks, specks) get no tone


@numba.njit(cache=True)
def _block_sum(a, lo, n):
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r = np.empty(8)
    for j in range(8):
        r[j] = a[lo + j]
    i = 8
    while i < n - (n % 8):
        for j in range(8):
            r[j] += a[lo + i + j]
        i += 8
    res = (r[0] + r[1]) + (r[2] + r[3]) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@numba.njit(cache=True)
def _pairwise_sum(a, lo, n):
    """``a[lo:lo + n].sum()`` for a contiguous float64 array: numpy's pairwise summation (8
    accumulators up to 128 values, halves at multiples of 8 above), so the sum and the threshold
    test on it are numpy's. The halving walks an explicit stack: numba's cached recursion
    crashes."""
    los = np.empty(64, np.int64)
    ns = np.empty(64, np.int64)
    left = np.empty(64)
    stage = np.zeros(64, np.int64)  # 0 new, 1 left half pending, 2 right half pending
    top, los[0], ns[0] = 0, lo, n
    result = 0.0
    while top >= 0:
        if ns[top] > 128 and stage[top] == 0:
            half = ns[top] // 2
            half -= half % 8
            stage[top] = 1
            top += 1
            los[top], ns[top], stage[top] = los[top - 1], half, 0
            continue
        result = _block_sum(a, los[top], ns[top])
        top -= 1
        while top >= 0:  # hand the finished half to its parent
            if stage[top] == 1:
                left[top] = result
                stage[top] = 2
                half = ns[top] // 2
                half -= half % 8
                top += 1
                los[top], ns[top], stage[top] = los[top - 1] + half, ns[top - 1] - half, 0
                break
            result = left[top] + result
            top -= 1
    return result


@numba.njit(cache=True)
def _tone(points, starts, rng, share, offset0, offset1):
    n = len(starts) - 1
    out = np.empty((2 * len(points), 2))
    out_starts = np.zeros(2 * n + 1, np.int64)
    o, m = 0, 0
    for k in range(n):
        i0, i1 = starts[k], starts[k + 1]
        pick, side, copies, span, start = rng.uniform(0.0, 1.0, 5)
        gaps = rng.uniform(offset0, offset1, 2)
        if pick >= share or i1 - i0 < 3:
            continue
        seg = np.empty(i1 - i0 - 1)
        for i in range(i0, i1 - 1):
            dx, dy = points[i + 1, 0] - points[i, 0], points[i + 1, 1] - points[i, 1]
            seg[i - i0] = np.sqrt(dx * dx + dy * dy)
        if _pairwise_sum(seg, 0, len(seg)) < MIN_LENGTH:
            continue
        count = i1 - i0
        keep = max(3, int(np.rint(count * (0.4 + 0.5 * span))))
        first = i0 + int(np.rint(start * (count - keep)))
        sign = 1.0 if side < 0.5 else -1.0
        for c in range(1 + int(copies < 0.5)):
            for i in range(first, first + keep):
                # np.gradient along the piece (one-sided at its ends), turned a quarter
                a, b = max(i - 1, first), min(i + 1, first + keep - 1)
                gx, gy = points[b, 0] - points[a, 0], points[b, 1] - points[a, 1]
                if b - a == 2:
                    gx, gy = gx / 2.0, gy / 2.0
                norm = max(np.sqrt(gy * gy + gx * gx), 1e-9)
                nx, ny = -gy / norm * sign, gx / norm * sign
                out[o, 0] = points[i, 0] + nx * gaps[c] * (c + 1)
                out[o, 1] = points[i, 1] + ny * gaps[c] * (c + 1)
                o += 1
            m += 1
            out_starts[m] = o
    return out[:o], out_starts[: m + 1]


def tone_strokes(
    strokes: list[np.ndarray], rng: np.random.Generator, share: float, offset: tuple[float, float]
) -> list[np.ndarray]:
    """Tone strokes (output px) for a ``share`` of ``strokes``: 1–2 copies each, shifted by
    ``offset`` px (uniform range) to one side, over a random 40–90 % of the stroke's length.
    Draws from ``rng`` in stroke order, a fixed number of values per stroke (compiled: one call
    for all strokes)."""
    points, starts = flat_strokes(strokes)
    out, out_starts = _tone(points, starts, rng, float(share), float(offset[0]), float(offset[1]))
    return split_strokes(out, out_starts)
