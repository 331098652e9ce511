"""Reading the binary PLY layout the prepare stage writes (pipeline.sources.mesh_io.ply_bytes:
little-endian float32 x, y, z per vertex, a uchar count and int32 indices per face) with numpy
alone: the embree render worker then starts without importing trimesh (~1.5 s CPU per batch).

Anything else (another layout, a damaged or truncated file) is not read here: ``read_plain_ply``
returns None and the caller uses its general loader, which says what is wrong.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

_VERTEX_PROPS = ["property float x", "property float y", "property float z"]
_FACE_PROP = "property list uchar int vertex_indices"
_MAX_HEADER = 4096


def _layout(header: list[str]) -> tuple[int, int] | None:
    """(vertices, faces) when the header is exactly the layout ply_bytes writes."""
    lines = [ln for ln in header if not ln.startswith("comment ")]
    if lines[:2] != ["ply", "format binary_little_endian 1.0"] or len(lines) != 9:
        return None
    v, f = lines[2].split(), lines[6].split()
    if v[:2] != ["element", "vertex"] or f[:2] != ["element", "face"] or len(v) != 3 or len(f) != 3:
        return None
    if lines[3:6] != _VERTEX_PROPS or lines[7] != _FACE_PROP or lines[8] != "end_header":
        return None
    if not (v[2].isdigit() and f[2].isdigit()):
        return None
    return int(v[2]), int(f[2])


def read_plain_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray] | None:
    """Vertices (n, 3) float64 and faces (m, 3) int64 exactly as stored, or None when the file
    is not a complete PLY of that layout with only triangles."""
    data = Path(path).read_bytes()
    end = data.find(b"end_header\n", 0, _MAX_HEADER)
    if end < 0:
        return None
    body = end + len(b"end_header\n")
    try:
        header = data[:body].decode("ascii").splitlines()
    except UnicodeDecodeError:
        return None
    counts = _layout(header)
    if counts is None:
        return None
    n_v, n_f = counts
    if len(data) != body + 12 * n_v + 13 * n_f:
        return None
    vertices = np.frombuffer(data, "<f4", 3 * n_v, body).reshape(n_v, 3).astype(np.float64)
    rows = np.frombuffer(data, np.dtype([("n", "u1"), ("i", "<i4", (3,))]), n_f, body + 12 * n_v)
    if n_f and not (rows["n"] == 3).all():
        return None
    return vertices, rows["i"].astype(np.int64)
