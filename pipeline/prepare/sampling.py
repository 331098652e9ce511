"""Area-uniform surface samples with unit outward normals."""

from __future__ import annotations

import numpy as np
import trimesh


def sample_surface(mesh: trimesh.Trimesh, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count, 6) float32: xyz then the unit normal of the face each point lies on.

    Faces are picked with probability proportional to their area, so the points are uniform over
    the surface; normals point outward because the mesh is oriented to positive volume first.
    """
    points, face_index = trimesh.sample.sample_surface(mesh, int(count), seed=rng)
    normals = mesh.face_normals[face_index]
    out = np.concatenate([points, normals], axis=1).astype(np.float32)
    # Renormalize after the float32 cast so every stored normal is unit to float32 precision.
    out[:, 3:] /= np.linalg.norm(out[:, 3:], axis=1, keepdims=True)
    return out
