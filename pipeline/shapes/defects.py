"""Mesh defects like those in scraped CAD collections, so downstream repair code sees them.

Kinds: ``holes`` (a patch of faces removed), ``flipped_faces`` (some faces wound inward),
``duplicate_faces`` (faces repeated), ``internal_faces`` (a stray quad inside a part's material).
Each applied defect is named ``<kind>:<part label>`` in the model's ``defects`` list.
"""

from __future__ import annotations

import numpy as np
import trimesh

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
    """A quad hidden in the part's material, halfway through it below a random face.

    The part's centroid would not do: for a hollow part (a mug's cup) it lies in the empty
    inside, and a quad there is a floating sheet, not internal faces.
    """
    mesh = trimesh.Trimesh(part.vertices, part.faces, process=False)
    f = int(rng.integers(len(part.faces)))
    n = mesh.face_normals[f]
    p = mesh.triangles_center[f]

    def crossings(direction: np.ndarray) -> np.ndarray:
        """Distances ahead of p at which the ray crosses another face, nearest first."""
        locs, _, hit = mesh.ray.intersects_location([p], [direction])
        t = (locs - p) @ direction
        return np.sort(t[(hit != f) & (t > 1e-9)])

    # Inward is the direction with an odd number of crossings ahead (an earlier flipped-faces
    # defect may have turned this face around).
    hits = crossings(-n)
    if len(hits) % 2 == 0:
        n = -n
        hits = crossings(-n)
    if len(hits) == 0:
        return  # not a closed part here (a hole right behind the face): leave it undamaged
    # Halfway to the first crossing is inside; the ball reaching to the nearest surface point is
    # too (a ray along a thin wall can run far before crossing), so the quad's corners stay in it.
    c = p - n * float(hits[0]) / 2
    clearance = float(trimesh.proximity.closest_point(mesh, c[None])[1][0])
    extent = float((part.vertices.max(axis=0) - part.vertices.min(axis=0)).max())
    half = min(0.6 * clearance / np.sqrt(2), 0.15 * extent)
    # two directions spanning the plane parallel to the face
    e = np.eye(3)[int(np.argmin(np.abs(n)))]
    u = np.cross(n, e)
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    quad = np.array([c + half * (su * u + sw * w) for su, sw in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    k = len(part.vertices)
    part.vertices = np.concatenate([part.vertices, quad])
    part.faces = np.concatenate([part.faces, np.array([[k, k + 1, k + 2], [k, k + 2, k + 3]])])


_APPLY = {"holes": _holes, "flipped_faces": _flipped, "duplicate_faces": _duplicate, "internal_faces": _internal}
