"""Checks on meshes: is the input usable at all, and is a repaired mesh a proper closed solid."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

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
        raise ModelError(
            path, f"huge mesh: coordinate {extent:.3g} beyond max_abs_coordinate {max_abs_coordinate:g}"
        )
    diag = float(np.linalg.norm(used.max(axis=0) - used.min(axis=0)))
    tri = vertices[faces]
    area = 0.5 * float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())
    # Relative to the bounding box so a tiny-but-valid model in metres isn't called degenerate.
    if diag == 0.0 or area <= 1e-12 * diag * diag:
        raise ModelError(path, f"degenerate mesh: total surface area {area:.3g} (bbox diagonal {diag:.3g})")


def closed_surface_problems(mesh: trimesh.Trimesh, max_bodies: int = 1) -> list[str]:
    """Reasons a mesh is not closed, consistently oriented, outward-facing solids, at most ``max_bodies`` ([] if it is)."""
    problems = []
    if len(mesh.faces) == 0:
        return ["no faces"]
    if not mesh.is_watertight:
        problems.append("not watertight (open or non-manifold edges)")
    if not mesh.is_winding_consistent:
        problems.append("inconsistent face orientation")
    bodies = mesh.body_count
    if bodies > max_bodies:
        problems.append(f"{bodies} separate volumes (max {max_bodies})")
    if not problems and not mesh.volume > 0:
        problems.append(f"non-positive enclosed volume {mesh.volume:.3g}")
    return problems
