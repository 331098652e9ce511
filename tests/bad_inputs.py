"""The bad-input corpus, generated into a folder at test time (no binaries in the repository).

``write_corpus(folder)`` writes one file per kind of bad input a real mesh collection holds, and
returns {model_id: words the recorded failure reason must contain}. Model ids are the file stems
(the folder source's naming), so the manifest's failure list can be checked file by file.
"""

from __future__ import annotations

import os
import socket
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
    return trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=False, include_attributes=False)


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
    expect["dangling"] = "broken link (points to"
    with socket.socket(socket.AF_UNIX) as sock:
        sock.bind(str(folder / "sock.ply"))
    expect["sock"] = "not a regular file but a socket"

    # Other files that are not meshes, whatever their name says.
    for name, magic, what in (
        ("scan.stl", b"\xff\xd8\xff\xe0", "a JPEG image"),
        ("parts.off", b"PK\x03\x04", "a ZIP archive"),
        ("manual.ply", b"%PDF-1.7", "a PDF document"),
        ("packed.obj", b"\x1f\x8b\x08", "a gzip archive"),
        ("tool.glb", b"\x7fELF\x02", "an executable"),
        ("anim.obj", b"GIF89a", "a GIF image"),
    ):
        (folder / name).write_bytes(magic + bytes(500))
        expect[Path(name).stem] = f"not a mesh: the file is {what}"
    (folder / "page.gltf").write_text("<html><body>404 not found</body></html>\n")
    expect["page"] = "not a mesh: text in no GLTF layout"
    (folder / "notes.obj").write_text("<html><body>a web page saved as .obj</body></html>\n")
    expect["notes"] = "empty mesh"

    # More wrong extensions.
    (folder / "ply_named_stl.stl").write_bytes(ply)
    expect["ply_named_stl"] = "wrong extension: named .stl but the content is PLY"
    off = trimesh.exchange.off.export_off(box)
    (folder / "off_named_obj.obj").write_text(off)
    expect["off_named_obj"] = "wrong extension: named .obj but the content is OFF"

    # Headers that disagree with the data.
    (folder / "stl_header_only.stl").write_bytes(bytes(80) + (12).to_bytes(4, "little"))
    expect["stl_header_only"] = "truncated: binary STL declares 12 triangles"
    (folder / "ply_no_end.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 8\n" + bytes(64))
    expect["ply_no_end"] = "truncated: PLY header has no end_header"
    glb = trimesh.exchange.gltf.export_glb(trimesh.Scene(box))
    (folder / "cut_glb.glb").write_bytes(glb[: len(glb) // 2])
    expect["cut_glb"] = "truncated: GLB header declares"
    lines = off.splitlines()
    lines[1] = "6 10 0"  # fewer than the file holds
    (folder / "off_counts.off").write_text("\n".join(lines) + "\n")
    expect["off_counts"] = "wrong OFF header counts: the header declares 6 vertices and 10 faces"
    (folder / "cut_off.off").write_text("\n".join(off.splitlines()[:12]) + "\n")
    expect["cut_off"] = "truncated or wrong OFF header counts: the header declares 8 vertices and 12 faces"
    (folder / "off_no_counts.off").write_text("OFF\n")
    expect["off_no_counts"] = "corrupt OFF: no vertex and face counts"
    ascii_ply = trimesh.exchange.ply.export_ply(box, encoding="ascii").decode()
    (folder / "cut_ascii_ply.ply").write_text("\n".join(ascii_ply.splitlines()[:-5]) + "\n")
    expect["cut_ascii_ply"] = "truncated: ASCII PLY header declares 20 data lines but the file has 15"

    # OBJ faces naming vertices wrongly.
    (folder / "face_zero.obj").write_text(_obj_text(box.vertices, box.faces).replace("f 1 ", "f 0 ", 1))
    expect["face_zero"] = "corrupt OBJ: face index 0 on line"
    (folder / "face_negative.obj").write_text(_obj_text(box.vertices, box.faces) + "f -20 1 2\n")
    expect["face_negative"] = "face indices out of range"

    # Geometry too small to be a solid.
    (folder / "two_faces.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n")
    expect["two_faces"] = "only 2 faces; a closed surface needs at least 4"
    (folder / "comments_only.obj").write_text("# nothing but comments\n# v 0 0 0\n")
    expect["comments_only"] = "empty mesh"
    v = box.vertices.copy()
    v[5] = np.nan
    (folder / "nan_off.off").write_text(trimesh.exchange.off.export_off(trimesh.Trimesh(v, box.faces, process=False)))
    expect["nan_off"] = "NaN"
    return expect


# Unusual files that are valid meshes and must build (with the good ones of write_good).
def write_unusual_good(folder: Path) -> list[str]:
    """A glTF with its buffer embedded, an OBJ starting with a UTF-8 byte order mark, a box
    1e-5 units across, and a model named like the pipeline's bookkeeping folder."""
    folder.mkdir(parents=True, exist_ok=True)
    box = trimesh.creation.box(extents=(1.0, 0.7, 0.5))
    gltf = trimesh.exchange.gltf.export_gltf(trimesh.Scene(box), embed_buffers=True)
    (folder / "embedded.gltf").write_bytes(gltf["model.gltf"])
    (folder / "bom.obj").write_bytes(b"\xef\xbb\xbf" + _obj_text(box.vertices, box.faces).encode())
    (folder / "tiny.obj").write_text(_obj_text(box.vertices * 1e-5, box.faces))
    (folder / "_batches.obj").write_text(_obj_text(box.vertices, box.faces))
    return ["embedded", "bom", "tiny", "_batches"]


# Bad build parameters: (BuildDataset parameters, words of the one-line error).
BAD_PARAMETERS = (
    (dict(batch_size=-1), "--batch-size must be an integer >= 1, got -1"),
    (dict(batch_size=0), "--batch-size must be an integer >= 1, got 0"),
    (dict(models_per_category=-1), "--models-per-category must be an integer >= 0"),
    (dict(views=0), "--views must be an integer >= 1, got 0"),
    (dict(variants=0), "--variants must be an integer >= 1"),
    (dict(image_size=4), "--image-size must be an integer >= 8"),
    (dict(categories="mgu"), "--categories: unknown 'mgu' for source"),
    (dict(categories=".."), "--categories: '..' is not a category name"),
    (dict(categories="mug/../../x"), "is not a category name"),
    (
        dict(prepare_settings='{"resolution": "abc"}'),
        "--prepare-settings: PrepareSettings.resolution must be an integer, got 'abc'",
    ),
    (dict(prepare_settings='{"resolution": -5}'), "--prepare-settings: resolution must be >= 1"),
    (dict(prepare_settings='{"resolution": 5000'), "--prepare-settings: not valid JSON"),
    (dict(prepare_settings="[1]"), "--prepare-settings: settings overrides must be a JSON object"),
    (
        dict(render_settings='{"elevation_range": [0]}'),
        "--render-settings: RenderSettings.elevation_range must be a list of 2",
    ),
    (
        dict(render_settings='{"smooth_shading": 1}'),
        "--render-settings: RenderSettings.smooth_shading must be true/false",
    ),
    (dict(augment_settings='{"nope": 1}'), "--augment-settings: AugmentSettings has no setting 'nope'"),
    (dict(shard_settings='{"max_samples_per_shard": 0}'), "--shard-settings: max_samples_per_shard"),
    (dict(max_failed_fraction=1.5), "--max-failed-fraction must lie in [0, 1]"),
)

# Pairs of files of one category that would be the same model: (names, words of the error).
CLASHES = (
    (("a.b.obj", "a_b.obj"), "'a.b.obj' and 'a_b.obj' would both be model 'mug_a_b'"),
    (("x.obj", "x.ply"), "'x.obj' and 'x.ply' would both be model 'mug_x'"),
    (("x.obj.stl", "x_obj.off"), "'x.obj.stl' and 'x_obj.off' would both be model 'mug_x_obj'"),
    (("Box.obj", "box.stl"), "'Box.obj' and 'box.stl' would both be model"),
)


def write_unreadable(path: Path) -> None:
    """A valid mesh whose mode gives nobody read access (root still reads it)."""
    box = trimesh.creation.box()
    path.write_text(_obj_text(box.vertices, box.faces))
    path.chmod(0)
