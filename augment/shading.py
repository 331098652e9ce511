"""Soft tone beside contours: the light, broad strokes a person shades a drawing with.

A person's pencil sketch is rarely clean lines only: the paper's released demo sketches are
lighter and broader than line drawings, with tone laid along the contours. ``tone_strokes``
gives a share of the strokes one or two companions shifted sideways along their normal (one side
per stroke, as shading sits on the shadow side of an edge), each covering a random stretch of
it; the rasterizer draws them lighter and broader than the lines.
"""

from __future__ import annotations

import numpy as np

MIN_LENGTH = 6.0  # output px: shorter strokes (ticks, specks) get no tone


def _normals(points: np.ndarray) -> np.ndarray:
    d = np.gradient(points, axis=0)
    n = np.stack([-d[:, 1], d[:, 0]], axis=1)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-9)


def tone_strokes(
    strokes: list[np.ndarray], rng: np.random.Generator, share: float, offset: tuple[float, float]
) -> list[np.ndarray]:
    """Tone strokes (output px) for a ``share`` of ``strokes``: 1–2 copies each, shifted by
    ``offset`` px (uniform range) to one side, over a random 40–90 % of the stroke's length.
    Draws from ``rng`` in stroke order, a fixed number of values per stroke."""
    out = []
    for s in strokes:
        s = np.asarray(s, np.float64)
        pick, side, copies, span, start = rng.uniform(size=5)
        gaps = rng.uniform(*offset, size=2)
        if pick >= share or len(s) < 3:
            continue
        length = float(np.linalg.norm(np.diff(s, axis=0), axis=1).sum())
        if length < MIN_LENGTH:
            continue
        n = len(s)
        keep = max(3, int(round(n * (0.4 + 0.5 * span))))
        first = int(round(start * (n - keep)))
        piece = s[first : first + keep]
        normal = _normals(piece) * (1.0 if side < 0.5 else -1.0)
        for k in range(1 + int(copies < 0.5)):
            out.append(piece + normal * gaps[k] * (k + 1))
    return out
