"""The page's 3D view of a prediction: its quad mesh as a GLB, each patch a tint of its own and
the patches the CAD kernel names (crossing or folded) in red.

GLB because the browser's viewer reads per-vertex colours from it; every triangle gets its own
three vertices so a patch's colour does not bleed into its neighbours.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from pipeline.core.atomic import write_bytes
from pipeline.core.thumbnails import DEFAULT_COLOR

CROSSING_COLOR = (0.9, 0.12, 0.1)
# light and dark tints alternate so neighbouring patches read apart
TINTS = np.array([1.0, 0.86, 0.93, 0.8])


def read_patch_obj(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices, triangles, patch of each triangle) of an OBJ written by ``train.export.obj``
    with ``g patch_<k>`` groups (``quads.obj``); quads are split in two."""
    vertices, tris, patch = [], [], []
    current = -1
    for line in Path(path).read_text().splitlines():
        if line.startswith("v "):
            vertices.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("g patch_"):
            current = int(line[len("g patch_") :])
        elif line.startswith("f "):
            idx = [int(t.split("/")[0]) - 1 for t in line.split()[1:]]
            for k in range(1, len(idx) - 1):  # a fan: quads -> 2 triangles
                tris.append([idx[0], idx[k], idx[k + 1]])
                patch.append(current)
    return np.asarray(vertices, np.float64), np.asarray(tris, np.int64).reshape(-1, 3), np.asarray(patch, np.int64)


def patch_colors(patch_of_tri: np.ndarray, crossing: list[int]) -> np.ndarray:
    """RGB in [0, 1] per triangle: the patch's tint, red for the ``crossing`` patches."""
    colors = np.asarray(DEFAULT_COLOR, np.float64)[None] * TINTS[patch_of_tri % len(TINTS), None]
    colors[np.isin(patch_of_tri, crossing)] = CROSSING_COLOR
    return colors


def write_view_glb(quads_obj: str | Path, crossing: list[int], path: str | Path) -> Path:
    """``quads_obj`` as a GLB at ``path`` with :func:`patch_colors`; returns ``path``."""
    vertices, tris, patch = read_patch_obj(quads_obj)
    rgb = np.repeat(patch_colors(patch, crossing), 3, axis=0)
    rgba = np.concatenate([np.round(255 * rgb), np.full((len(rgb), 1), 255)], axis=1).astype(np.uint8)
    mesh = trimesh.Trimesh(
        vertices[tris].reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3), vertex_colors=rgba, process=False
    )
    write_bytes(path, mesh.export(file_type="glb"))
    return Path(path)
