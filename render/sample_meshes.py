"""Small normalized test meshes (trimesh primitives) written as PLY: inputs for tests and benches
that must not depend on the prepare stage."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from pipeline.core.atomic import atomic_path


def normalized(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Bounding-box centre to the origin, farthest vertex at radius 1 (the prepare convention)."""
    v = mesh.vertices - mesh.bounds.mean(axis=0)
    v = v / np.linalg.norm(v, axis=1).max()
    return trimesh.Trimesh(v, mesh.faces, process=False)


def box_on_cylinder() -> trimesh.Trimesh:
    """A box with an upright cylinder standing on it (touching, not intersecting)."""
    box = trimesh.creation.box((1.0, 0.6, 0.8))
    cyl = trimesh.creation.cylinder(radius=0.25, height=0.6, sections=48)
    cyl.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    cyl.apply_translation((0.0, 0.3 + 0.3, 0.0))
    return normalized(trimesh.util.concatenate([box, cyl]))


def capsule() -> trimesh.Trimesh:
    return normalized(trimesh.creation.capsule(height=1.2, radius=0.35, count=[24, 24]))


def wedge() -> trimesh.Trimesh:
    """A triangular prism: only creases and silhouettes, sharp corners."""
    tri = np.array([[0.0, 0.0], [1.2, 0.0], [0.2, 0.8]])
    v = np.array([[x, y, z] for z in (-0.25, 0.25) for x, y in tri])
    f = np.array(
        [
            [0, 2, 1],
            [3, 4, 5],  # ends
            [0, 1, 4],
            [0, 4, 3],
            [1, 2, 5],
            [1, 5, 4],
            [2, 0, 3],
            [2, 3, 5],
        ]
    )
    mesh = trimesh.Trimesh(v, f, process=False)
    mesh.fix_normals()
    return normalized(mesh)


def sphere_with_faces(n_faces: int) -> trimesh.Trimesh:
    """A UV sphere with about ``n_faces`` triangles (for timing at a given size)."""
    k = max(3, int(round(np.sqrt(n_faces / 4.0))))
    return normalized(trimesh.creation.uv_sphere(radius=1.0, count=[k, k]))


def write_ply(mesh: trimesh.Trimesh, path: Path) -> Path:
    with atomic_path(path) as tmp:
        mesh.export(tmp, file_type="ply")
    return Path(path)


def write_samples(folder: Path) -> list[tuple[str, Path]]:
    """Write the three test meshes as ``<folder>/<id>.ply``; returns (model_id, path) pairs."""
    folder = Path(folder)
    shapes = {"box_cyl": box_on_cylinder(), "capsule": capsule(), "wedge": wedge()}
    return [(name, write_ply(mesh, folder / f"{name}.ply")) for name, mesh in shapes.items()]
