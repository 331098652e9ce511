"""Mesh defects like those in scraped CAD collections, so downstream repair code sees them.

Kinds: ``holes`` (a patch of faces removed), ``flipped_faces`` (some faces wound inward),
``duplicate_faces`` (faces repeated), ``internal_faces`` (a stray quad inside a part).
Each applied defect is named ``<kind>:<part label>`` in the model's ``defects`` list.
"""

from __future__ import annotations

import numpy as np

from pipeline.shapes.model import Part

KINDS = ("holes", "flipped_faces", "duplicate_faces", "internal_faces")


def apply_defects(parts: list[Part], rng: np.random.Generator, fraction: float) -> list[str]:
    """With probability ``fraction`` damage 1-2 random parts in place; return what was done."""
    # Always draw the same numbers so the decision does not shift the rest of the stream.
    roll = rng.random()
    n_defects = int(rng.integers(1, 3))
    kinds = rng.choice(len(KINDS), size=n_defects, replace=False)
    targets = rng.integers(0, len(parts), size=n_defects)
    if roll >= fraction:
        return []
    done = []
    for kind_i, part_i in zip(kinds, targets):
        kind = KINDS[int(kind_i)]
        part = parts[int(part_i)]
        _APPLY[kind](part, rng)
        done.append(f"{kind}:{part.label}")
    return done


def _nearby_faces(part: Part, rng: np.random.Generator, count: int) -> np.ndarray:
    """Indices of ``count`` faces closest to a random face (a compact patch)."""
    centers = part.vertices[part.faces].mean(axis=1)
    seed_face = int(rng.integers(len(part.faces)))
    d = np.linalg.norm(centers - centers[seed_face], axis=1)
    return np.argsort(d, kind="stable")[: max(1, min(count, len(part.faces) - 4))]


def _holes(part: Part, rng: np.random.Generator) -> None:
    drop = _nearby_faces(part, rng, int(rng.integers(2, 12)))
    part.faces = np.delete(part.faces, drop, axis=0)


def _flipped(part: Part, rng: np.random.Generator) -> None:
    flip = _nearby_faces(part, rng, int(rng.integers(4, 40)))
    part.faces = part.faces.copy()
    part.faces[flip] = part.faces[flip][:, ::-1]


def _duplicate(part: Part, rng: np.random.Generator) -> None:
    dup = _nearby_faces(part, rng, int(rng.integers(4, 40)))
    part.faces = np.concatenate([part.faces, part.faces[dup]])


def _internal(part: Part, rng: np.random.Generator) -> None:
    """A quad through the part's centroid, spanning part of its bounding box."""
    used = part.vertices[np.unique(part.faces)]
    c = used.mean(axis=0)
    half = (used.max(axis=0) - used.min(axis=0)) * 0.15
    axis = int(rng.integers(3))  # the quad's normal axis
    a, b = [i for i in range(3) if i != axis]
    quad = np.tile(c, (4, 1))
    for j, (sa, sb) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
        quad[j, a] += sa * half[a]
        quad[j, b] += sb * half[b]
    n = len(part.vertices)
    part.vertices = np.concatenate([part.vertices, quad])
    part.faces = np.concatenate([part.faces, np.array([[n, n + 1, n + 2], [n, n + 2, n + 3]])])


_APPLY = {"holes": _holes, "flipped_faces": _flipped, "duplicate_faces": _duplicate, "internal_faces": _internal}
