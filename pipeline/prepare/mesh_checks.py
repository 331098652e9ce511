"""Checks on meshes: is the input usable at all, and is a repaired mesh a proper closed solid."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from pipeline.core.errors import ModelError


def check_input(
    path: str | Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    max_faces: int,
    max_abs_coordinate: float,
) -> None:
    """Raise ModelError if a loaded mesh is empty, non-finite, huge or has zero area."""
    if len(faces) == 0 or len(vertices) == 0:
        raise ModelError(path, "empty mesh: no faces")
    if len(faces) < 4:
        # fewer faces than a tetrahedron can't bound a solid: nothing for watertighting to recover
        what = "a single face" if len(faces) == 1 else f"only {len(faces)} faces"
        raise ModelError(path, f"degenerate mesh: {what}; a closed surface needs at least 4")
    if len(faces) > max_faces:
        raise ModelError(path, f"huge mesh: {len(faces)} faces > max_input_faces {max_faces}")
    if not np.isfinite(vertices).all():
        bad = int((~np.isfinite(vertices)).any(axis=1).sum())
        raise ModelError(path, f"non-finite coordinates: {bad} vertices are NaN or infinite")
    used = vertices[np.unique(faces)]
    extent = float(np.abs(used).max())
    if extent > max_abs_coordinate:
        raise ModelError(path, f"huge mesh: coordinate {extent:.3g} beyond max_abs_coordinate {max_abs_coordinate:g}")
    diag = float(np.linalg.norm(used.max(axis=0) - used.min(axis=0)))
    tri = vertices[faces]
    area = 0.5 * float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())
    # Relative to the bounding box so a tiny-but-valid model in metres isn't called degenerate.
    if diag == 0.0 or area <= 1e-12 * diag * diag:
        raise ModelError(path, f"degenerate mesh: total surface area {area:.3g} (bbox diagonal {diag:.3g})")


@dataclasses.dataclass(frozen=True)
class SurfaceFacts:
    """What the repair checks ask of a triangle mesh, with trimesh's meanings: ``watertight``
    (every edge in exactly two faces), ``winding_consistent`` (every edge in exactly two faces runs
    opposite ways in them), ``face_parts`` (groups of faces joined across such edges, as
    ``mesh.split`` counts), ``bodies`` (groups of joined vertices, ``mesh.body_count``) and
    ``volume`` (signed; positive for an outward-facing closed surface), and the face count."""

    faces: int
    watertight: bool
    winding_consistent: bool
    face_parts: int
    bodies: int
    volume: float


def surface_facts(vertices: np.ndarray, faces: np.ndarray) -> SurfaceFacts:
    """:class:`SurfaceFacts` from one sort of the edges. trimesh answers the same questions from
    separately cached properties that the repair's checks kept recomputing (~0.1 CPU s per
    envelope, BENCHMARKS.md); the answers are equal (tests/test_prepare_core.py)."""
    faces = np.asarray(faces, dtype=np.int64)
    vertices = np.asarray(vertices, dtype=np.float64)
    n_f, n_v = len(faces), len(vertices)
    edges = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)  # edge k belongs to face k // 3
    key = np.minimum(edges[:, 0], edges[:, 1]) * n_v + np.maximum(edges[:, 0], edges[:, 1])
    order = np.argsort(key, kind="stable")
    key = key[order]
    new_run = np.r_[True, key[1:] != key[:-1]]
    starts = np.flatnonzero(new_run)
    counts = np.diff(np.r_[starts, len(key)])
    twice = starts[counts == 2]
    first, second = order[twice], order[twice + 1]  # the two uses of each edge in exactly two faces
    watertight = bool(len(twice) * 2 == len(edges))
    winding = bool(np.all(edges[first, 1] == edges[second, 0]))
    adjacency = coo_matrix((np.ones(len(first), np.int8), (first // 3, second // 3)), shape=(n_f, n_f))
    face_parts = connected_components(adjacency, directed=False)[0] if n_f else 0
    vertex_graph = coo_matrix((np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(n_v, n_v))
    bodies = connected_components(vertex_graph, directed=False)[0] if n_v else 0
    tri = vertices[faces]
    volume = float(np.einsum("ij,ij->", tri[:, 0], np.cross(tri[:, 1], tri[:, 2]))) / 6.0
    return SurfaceFacts(n_f, watertight, winding, int(face_parts), int(bodies), volume)


def closed_surface_problems(facts: SurfaceFacts, max_bodies: int = 1) -> list[str]:
    """Reasons a mesh with these :func:`surface_facts` is not closed, consistently oriented,
    outward-facing solids, at most ``max_bodies`` ([] if it is)."""
    if facts.faces == 0:
        return ["no faces"]
    problems = []
    if not facts.watertight:
        problems.append("not watertight (open or non-manifold edges)")
    if not facts.winding_consistent:
        problems.append("inconsistent face orientation")
    if facts.bodies > max_bodies:
        problems.append(f"{facts.bodies} separate volumes (max {max_bodies})")
    if not problems and not facts.volume > 0:
        problems.append(f"non-positive enclosed volume {facts.volume:.3g}")
    return problems
