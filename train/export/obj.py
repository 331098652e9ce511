"""OBJ writers for exported meshes (triangles or quads, 1-based indices, fixed float format)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.core.atomic import write_bytes


def obj_text(
    vertices: np.ndarray, faces: np.ndarray, groups: np.ndarray | None = None, comments: list[str] | None = None
) -> str:
    """OBJ text; ``groups`` (per face) starts a new ``g patch_<k>`` whenever it changes;
    ``comments`` become ``#`` lines at the top (metadata that OBJ readers skip)."""
    lines = [f"# {c}" for c in comments or []]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in np.asarray(vertices, dtype=np.float64)]
    current = None
    for k, face in enumerate(np.asarray(faces)):
        if groups is not None and groups[k] != current:
            current = groups[k]
            lines.append(f"g patch_{int(current)}")
        lines.append("f " + " ".join(str(int(i) + 1) for i in face))
    return "\n".join(lines) + "\n"


def write_obj(
    path: str | Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    groups: np.ndarray | None = None,
    comments: list[str] | None = None,
) -> None:
    write_bytes(path, obj_text(vertices, faces, groups, comments).encode())


def edge_report(faces: np.ndarray) -> dict:
    """Watertight/manifold check: every edge in exactly two faces, once in each direction."""
    faces = np.asarray(faces)
    k = faces.shape[1]
    directed = np.concatenate([faces[:, [i, (i + 1) % k]] for i in range(k)])
    undirected = np.sort(directed, axis=1)
    _, counts = np.unique(undirected, axis=0, return_counts=True)
    _, dcounts = np.unique(directed, axis=0, return_counts=True)
    return {
        "boundary_edges": int((counts == 1).sum()),
        "nonmanifold_edges": int((counts > 2).sum()),
        "inconsistent_edges": int((dcounts > 1).sum()),
        "watertight": bool((counts == 2).all() and (dcounts == 1).all()),
    }
