"""Readers for the two game-mesh formats fetch_games.py converts, and a plain OBJ writer.

* AC3D (``.ac``/``.acc``, TORCS): a text tree of OBJECTs, each with a ``loc`` offset (added to
  its own and its children's vertices), ``numvert`` vertices and SURFs. A SURF's low nibble says
  what its refs are: 0 a polygon (fanned), 1/2 lines (dropped), 4 a triangle strip (TORCS's
  ``.acc`` extension; every other triangle flipped to keep the strip's winding).
* 3DS (GL-117): binary chunks (id uint16, length uint32 counting the 6-byte header). Meshes are
  ``0x4D4D main > 0x3D3D editor > 0x4000 named object > 0x4100 triangle mesh`` with ``0x4110``
  vertices (float32, in the scene's frame), ``0x4120`` faces (three uint16 and a flag word each)
  and ``0x4160`` the mesh's local frame (a left-handed one: a mirrored copy, placed by
  mirroring); everything else (materials, keyframes) is skipped by its length.

Both return (vertices (n, 3) float64, faces (m, 3) int64) and raise ValueError on a malformed file.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

_STRIP, _POLYGON = 4, 0


def read_ac3d(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of an AC3D file; ``rot`` matrices are ignored (TORCS bodies have none)."""
    lines = [ln.split() for ln in text.splitlines()]
    vertices: list[list[float]] = []
    faces: list[tuple[int, int, int]] = []
    pos = _next_object(lines, 0)
    if pos is None:
        raise ValueError("no OBJECT in the AC3D file")
    _read_object(lines, pos + 1, np.zeros(3), vertices, faces)
    return np.asarray(vertices, np.float64).reshape(-1, 3), np.asarray(faces, np.int64).reshape(-1, 3)


def _next_object(lines: list[list[str]], pos: int) -> int | None:
    while pos < len(lines) and not (lines[pos] and lines[pos][0] == "OBJECT"):
        pos += 1
    return pos if pos < len(lines) else None


def _read_object(lines: list[list[str]], pos: int, parent: np.ndarray, vertices: list, faces: list) -> int:
    """Reads one OBJECT's body from ``pos`` (after its header) and its kids; returns the next line."""
    loc, base = np.zeros(3), len(vertices)
    while pos < len(lines):
        words = lines[pos]
        pos += 1
        if not words:
            continue
        if words[0] == "loc":
            loc = np.array([float(x) for x in words[1:4]])
        elif words[0] == "numvert":
            base, offset = len(vertices), parent + loc
            for k in range(int(words[1])):
                vertices.append([float(x) + o for x, o in zip(lines[pos + k][:3], offset)])
            pos += int(words[1])
        elif words[0] == "SURF":
            pos = _read_surface(lines, pos, int(words[1], 16) & 0xF, base, faces)
        elif words[0] == "kids":
            for _ in range(int(words[1])):
                start = _next_object(lines, pos)
                if start is None:
                    raise ValueError("AC3D file ends before all kids were read")
                pos = _read_object(lines, start + 1, parent + loc, vertices, faces)
            return pos
    return pos


def _read_surface(lines: list[list[str]], pos: int, kind: int, base: int, faces: list) -> int:
    while pos < len(lines) and not (lines[pos] and lines[pos][0] == "refs"):
        pos += 1  # mat line
    if pos >= len(lines):
        raise ValueError("AC3D SURF without refs")
    n = int(lines[pos][1])
    idx = [base + int(lines[pos + 1 + k][0]) for k in range(n)]
    if kind == _STRIP:
        for k in range(n - 2):
            a, b, c = idx[k], idx[k + 1], idx[k + 2]
            faces.append((a, b, c) if k % 2 == 0 else (b, a, c))
    elif kind == _POLYGON:
        faces.extend((idx[0], idx[k], idx[k + 1]) for k in range(1, n - 1))
    return pos + 1 + n


_MAIN, _EDITOR, _OBJECT, _TRIMESH, _VERTICES, _FACES, _MATRIX = 0x4D4D, 0x3D3D, 0x4000, 0x4100, 0x4110, 0x4120, 0x4160


def _unmirror(vertices: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """A mirrored object's vertices where the scene shows it. ``frame`` is the mesh's local frame
    (rows: x, y, z axes, origin); when it is left-handed (a mirrored copy) the stored vertices are
    the unmirrored part's, and the part sits mirrored in its local x (as assimp and lib3ds read it:
    measured on GL-117's mirrored tanks, 0.05-0.12 units off otherwise)."""
    axes, origin = frame[:3].T, frame[3]
    if np.linalg.det(axes) >= 0:
        return vertices
    flip = axes @ np.diag([-1.0, 1.0, 1.0]) @ np.linalg.inv(axes)
    return (vertices - origin) @ flip.T + origin


def read_3ds(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of every triangle mesh in a 3DS file, concatenated."""
    vertices: list[np.ndarray] = []
    faces: list[np.ndarray] = []
    for cid, start, end in _chunks(data, 0, len(data)):
        if cid == _MAIN:
            _read_3ds_meshes(data, start, end, vertices, faces)
    if not faces:
        raise ValueError("no triangle mesh in the 3DS file")
    return np.concatenate(vertices), np.concatenate(faces)


def _chunks(data: bytes, start: int, end: int):
    """(id, body start, body end) of each chunk between start and end."""
    while start + 6 <= end:
        cid, length = struct.unpack_from("<HI", data, start)
        if length < 6 or start + length > end:
            raise ValueError(f"3DS chunk {cid:#06x} at {start} runs past its parent")
        yield cid, start + 6, start + length
        start += length


def _read_3ds_meshes(data: bytes, start: int, end: int, vertices: list, faces: list) -> None:
    for cid, s, e in _chunks(data, start, end):
        if cid == _EDITOR:
            _read_3ds_meshes(data, s, e, vertices, faces)
        elif cid == _OBJECT:
            name_end = data.index(b"\0", s, e) + 1  # the object's name, a C string
            _read_3ds_meshes(data, name_end, e, vertices, faces)
        elif cid == _TRIMESH:
            v = f = frame = None
            for sub, ss, _ in _chunks(data, s, e):
                if sub == _VERTICES:
                    n = struct.unpack_from("<H", data, ss)[0]
                    v = np.frombuffer(data, "<f4", 3 * n, ss + 2).reshape(n, 3).astype(np.float64)
                elif sub == _FACES:
                    n = struct.unpack_from("<H", data, ss)[0]
                    f = np.frombuffer(data, "<u2", 4 * n, ss + 2).reshape(n, 4)[:, :3].astype(np.int64)
                elif sub == _MATRIX:
                    frame = np.frombuffer(data, "<f4", 12, ss).reshape(4, 3).astype(np.float64)
            if v is not None and f is not None and len(f):
                if f.max() >= len(v):
                    raise ValueError("3DS face refers past its mesh's vertices")
                if frame is not None:
                    v = _unmirror(v, frame)
                offset = sum(len(x) for x in vertices)
                vertices.append(v)
                faces.append(f + offset)


def write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """``v`` and ``f`` lines only (1-based), 6 decimals: what the pipeline's folder source reads."""
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in np.asarray(vertices, float).tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(faces, int).tolist()]
    Path(path).write_text("\n".join(lines) + "\n")
