"""The bad-input corpus, generated into a folder at test time (no binaries in the repository).

``write_corpus(folder)`` writes one file per kind of bad input a real mesh collection holds, and
returns {model_id: words the recorded failure reason must contain}. Model ids are the file stems
(the folder source's naming), so the manifest's failure list can be checked file by file.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh

# Written by write_good(): the models that must reach the shards.
GOOD = ("good_box", "good_sphere")


def _obj_text(vertices, faces) -> str:
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(vertices, float).tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(faces, int).tolist()]
    return "\n".join(lines) + "\n"


def _binary_stl(mesh: trimesh.Trimesh) -> bytes:
    return trimesh.exchange.stl.export_stl(mesh)


def _binary_ply(mesh: trimesh.Trimesh) -> bytes:
    return trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=False,
                                           include_attributes=False)


def write_good(folder: Path) -> list[str]:
    """Two small valid meshes (OBJ and binary STL)."""
    folder.mkdir(parents=True, exist_ok=True)
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    (folder / "good_box.obj").write_text(_obj_text(box.vertices, box.faces))
    (folder / "good_sphere.stl").write_bytes(_binary_stl(trimesh.creation.icosphere(2)))
    return list(GOOD)


def write_corpus(folder: Path) -> dict[str, str]:
    """Write the bad files into ``folder``; returns {model_id: expected words of the reason}."""
    folder.mkdir(parents=True, exist_ok=True)
    box = trimesh.creation.box()
    expect: dict[str, str] = {}

    # Files that are not meshes at all.
    (folder / "photo.obj").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    expect["photo"] = "not a mesh: the file is a PNG image"
    (folder / "random_bytes.ply").write_bytes(np.random.default_rng(0).bytes(2048).replace(b"ply", b"xxx"))
    expect["random_bytes"] = "not a mesh"
    (folder / "readme.off").write_text("This folder holds the meshes of the collection.\n")
    expect["readme"] = "not a mesh"

    # Truncated files: cut in the middle of their data.
    ply = _binary_ply(trimesh.creation.icosphere(2))
    (folder / "cut_ply.ply").write_bytes(ply[: len(ply) // 2])
    expect["cut_ply"] = "truncated"
    stl = _binary_stl(trimesh.creation.icosphere(2))
    (folder / "cut_stl.stl").write_bytes(stl[: len(stl) // 3])
    expect["cut_stl"] = "truncated"
    (folder / "cut_obj.obj").write_text(_obj_text(box.vertices[:4], box.faces))  # faces name lost vertices
    expect["cut_obj"] = "face indices out of range"

    # Empty meshes.
    (folder / "zero_bytes.obj").write_bytes(b"")
    expect["zero_bytes"] = "empty mesh: file has 0 bytes"
    (folder / "no_faces.obj").write_text("# exported with no geometry\nv 0 0 0\nv 1 0 0\n")
    expect["no_faces"] = "empty mesh"

    # Bad coordinates.
    v = box.vertices.copy()
    v[3, 1] = np.nan
    (folder / "nan_coords.obj").write_text(_obj_text(v, box.faces))
    expect["nan_coords"] = "NaN"
    v = box.vertices.copy()
    v[0, 0] = np.inf
    (folder / "inf_coords.obj").write_text(_obj_text(v, box.faces))
    expect["inf_coords"] = "infinite"
    (folder / "huge_coords.obj").write_text(_obj_text(box.vertices * 1e30, box.faces))
    expect["huge_coords"] = "huge mesh: coordinate"

    # Degenerate geometry.
    (folder / "one_face.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    expect["one_face"] = "single face"
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], float)
    (folder / "zero_area.obj").write_text(_obj_text(line, [[0, 1, 2], [1, 2, 3], [0, 1, 3], [0, 2, 3]]))
    expect["zero_area"] = "degenerate mesh: total surface area 0"
    rng = np.random.default_rng(1)  # far-apart slivers: no volume can be recovered from them
    soup_v = (rng.uniform(-1, 1, (60, 1, 3)) * 10 + rng.normal(0, 0.01, (60, 3, 3))).reshape(-1, 3)
    (folder / "soup.obj").write_text(_obj_text(soup_v, np.arange(180).reshape(60, 3)))
    expect["soup"] = "repair failed verification"

    # Wrong extension: an STL named .obj, an OBJ named .ply.
    (folder / "stl_named_obj.obj").write_bytes(_binary_stl(box))
    expect["stl_named_obj"] = "wrong extension: named .obj but the content is STL"
    (folder / "obj_named_ply.ply").write_text(_obj_text(box.vertices, box.faces))
    expect["obj_named_ply"] = "wrong extension: named .ply but the content is OBJ"

    # Not a regular file: a folder and a named pipe named like meshes.
    (folder / "folder.obj").mkdir()
    expect["folder"] = "not a regular file but a directory"
    os.mkfifo(folder / "pipe.stl")
    expect["pipe"] = "not a regular file but a FIFO"
    (folder / "dangling.obj").symlink_to(folder / "does_not_exist.obj")
    expect["dangling"] = "file not found"
    return expect


def write_unreadable(path: Path) -> None:
    """A valid mesh whose mode gives nobody read access (root still reads it)."""
    box = trimesh.creation.box()
    path.write_text(_obj_text(box.vertices, box.faces))
    path.chmod(0)

