"""Reading source meshes and writing prepared ones.

Loading turns any supported file (OBJ, OFF, PLY, STL, GLB/GLTF) into one triangle soup (float64
vertices, int64 faces), flattening scene graphs with their transforms. Every failure becomes a
ModelError naming the file, so a batch can record it and move on.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import trimesh

from pipeline.atomic import write_bytes
from pipeline.errors import ModelError

MESH_EXTENSIONS = (".obj", ".off", ".ply", ".stl", ".glb", ".gltf")


def sha256_file(path: str | Path, chunk: int = 1 << 20) -> str:
    """Hex sha256 of a file, read in chunks so huge meshes don't sit in memory twice."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def load_mesh(path: str | Path, max_bytes: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n,3) float64 and triangle faces (m,3) int64 of a mesh file.

    Raises ModelError for a missing, oversized or unparsable file, or one without triangles.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelError(path, "unreadable: file not found")
    if path.suffix.lower() not in MESH_EXTENSIONS:
        raise ModelError(path, f"unreadable: unsupported extension {path.suffix!r}")
    size = path.stat().st_size
    if size == 0:
        raise ModelError(path, "empty mesh: file has 0 bytes")
    if max_bytes is not None and size > max_bytes:
        raise ModelError(path, f"huge mesh: file is {size} bytes > max_input_bytes {max_bytes}")
    try:
        # force="mesh" flattens scenes (GLB, multi-object OBJ) applying node transforms;
        # process=False keeps the file's vertices untouched (watertighting repairs them anyway).
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # parsers raise anything from ValueError to struct.error
        raise ModelError(path, f"unreadable: {type(exc).__name__}: {exc}") from exc
    if not isinstance(loaded, trimesh.Trimesh):
        # An empty scene (nothing parsable in the file) comes back as a Scene or a point cloud.
        raise ModelError(path, f"empty mesh: no triangles found (got {type(loaded).__name__})")
    vertices = np.asarray(loaded.vertices, dtype=np.float64)
    faces = np.asarray(loaded.faces, dtype=np.int64)
    if faces.ndim != 2 or len(faces) == 0 or len(vertices) == 0:
        raise ModelError(path, "empty mesh: no faces")
    if faces.shape[1] != 3:
        raise ModelError(path, f"unreadable: faces have {faces.shape[1]} corners, expected 3")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ModelError(path, "unreadable: face indices out of range")
    return vertices, faces


def ply_bytes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """Binary little-endian PLY (float32 xyz, int32 indices); equal arrays give equal bytes."""
    mesh = trimesh.Trimesh(
        np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64), process=False
    )
    return trimesh.exchange.ply.export_ply(
        mesh, encoding="binary", vertex_normal=False, include_attributes=False
    )


def write_ply(path: str | Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a mesh as binary PLY atomically."""
    write_bytes(path, ply_bytes(vertices, faces))


def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of a PLY written by write_ply, exactly as stored (no merging)."""
    mesh = trimesh.load(str(path), force="mesh", process=False)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
