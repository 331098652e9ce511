"""A source mesh's segmentation: (raw part name, vertices, faces) per part, when the file has one.

In order of preference:

1. what the file carries: OBJ ``g`` groups (else ``o`` objects), glTF/GLB nodes (their transforms
   applied; node name, else mesh name), PLY per-face labels (a face property ``label``, ``part``,
   ``segment`` or ``class``; or such a vertex property, a face taking its first vertex's); not
   for ShapeNetCore's ``models/model_normalized.obj``, whose groups are per material;
2. a per-point label file beside the mesh, the ShapeNet-part convention: ``<stem>.pts`` (one
   ``x y z`` per line) + ``<stem>.seg`` (one integer per line), also looked up as
   ``points/<id>.pts`` + ``points_label/<id>.seg`` under the mesh's folder or a ``labels_dir``
   (the ShapeNet-part benchmark's own layout). Faces take the label of the point nearest their
   centre, both sets normalized to the unit sphere first (ShapeNet-part points are not in
   ShapeNetCore's scale; the axes must agree). Labels are named ``seg<N>``; a part map renames them.

``None`` means no segmentation (one part or none). The mesh itself is loaded by
``pipeline.sources.mesh_io.load_mesh`` (validation, error messages); this module only reads the
part structure. Two readers share it, so a template's part names and a shard's part labels are
the same names: ``train.templates`` (part boxes of a user's category) and the prepare stage
(``named_parts``: the part labels of a file source's models).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from pipeline.core.errors import ModelError
from pipeline.core.normalize import apply_transform, unit_sphere_transform
from pipeline.core.settings_io import setting
from pipeline.sources.layouts import SHAPENET_MODEL_FILE
from pipeline.sources.part_names import map_name

PLY_LABEL_NAMES = ("label", "part", "segment", "class", "part_id", "segment_id")


@dataclass
class RawPart:
    name: str
    vertices: np.ndarray  # (n, 3) source frame
    faces: np.ndarray  # (m, 3) into vertices
    is_id: bool = False  # name is an id (seg3): not normalized like a free name


@dataclass
class Segmentation:
    parts: list[RawPart]
    origin: str  # "obj groups", "gltf nodes", "ply labels", "points file"


def read_segmentation(
    path: Path, vertices: np.ndarray, faces: np.ndarray, model_id: str = "", labels_dir: Path | None = None
) -> Segmentation | None:
    """The mesh's parts (see module docstring), or None when it carries no segmentation.

    ``vertices``/``faces``: the mesh as ``load_mesh`` read it (used for label-file transfer)."""
    ext = path.suffix.lower()
    seg = None
    if _is_shapenet_core(path):
        pass  # ShapeNetCore's groups are material groups ("mesh12-geometry"), not parts: only its points files
    elif ext == ".obj":
        seg = _obj_groups(path)
    elif ext in (".glb", ".gltf"):
        seg = _gltf_nodes(path)
    elif ext == ".ply":
        seg = _ply_labels(path)
    if seg is not None and len({p.name for p in seg.parts}) > 1:
        return seg
    points = find_points_file(path, model_id, labels_dir)
    if points is not None:
        return points_segmentation(vertices, faces, *points)
    return None


def _is_shapenet_core(path: Path) -> bool:
    return Path(path).parts[-len(SHAPENET_MODEL_FILE.parts) :] == SHAPENET_MODEL_FILE.parts


def _obj_groups(path: Path) -> Segmentation | None:
    """Faces per ``g`` name (``o`` when the file has no groups); polygons fanned into triangles."""
    verts: list[list[float]] = []
    by: dict[str, dict[str, list[list[int]]]] = {"g": {}, "o": {}}
    cur = {"g": "", "o": ""}
    try:
        text = path.read_text(encoding="utf-8-sig", errors="replace")
    except OSError as exc:
        raise ModelError(path, f"unreadable: {exc.strerror or exc}") from None
    for line in text.splitlines():
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        head = words[0]
        if head == "v" and len(words) >= 4:
            verts.append([float(x) for x in words[1:4]])
        elif head in ("g", "o"):
            cur[head] = " ".join(words[1:2]) or ""  # "g a b" puts faces in several groups: the first names them
        elif head == "f" and len(words) >= 4:
            idx = [int(w.split("/")[0]) for w in words[1:]]
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]  # OBJ counts from 1, negatives from the end
            tris = [[idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1)]
            for key in ("g", "o"):
                by[key].setdefault(cur[key], []).extend(tris)
    key = "g" if len([k for k in by["g"] if k]) > 1 else "o"
    groups = {k: v for k, v in by[key].items() if v}
    if len(groups) < 2:
        return None
    allv = np.asarray(verts, np.float64).reshape(-1, 3)
    parts = [RawPart(name or "ungrouped", allv, np.asarray(f, np.int64)) for name, f in groups.items()]
    return Segmentation(parts, f"obj {'groups' if key == 'g' else 'objects'}")


def _gltf_nodes(path: Path) -> Segmentation | None:
    import trimesh

    scene = trimesh.load(str(path), process=False)
    if not isinstance(scene, trimesh.Scene):
        return None
    parts = []
    for node in scene.graph.nodes_geometry:
        matrix, geom = scene.graph[node]
        mesh = scene.geometry.get(geom)
        if not isinstance(mesh, trimesh.Trimesh) or not len(mesh.faces):
            continue
        v = trimesh.transform_points(np.asarray(mesh.vertices, np.float64), matrix)
        parts.append(RawPart(str(node or geom), v, np.asarray(mesh.faces, np.int64)))
    return Segmentation(parts, "gltf nodes") if len(parts) > 1 else None


def _ply_labels(path: Path) -> Segmentation | None:
    import trimesh

    mesh = trimesh.load(str(path), process=False)
    raw = getattr(mesh, "metadata", {}).get("_ply_raw", {})
    faces = np.asarray(mesh.faces, np.int64)
    labels = None
    for element in ("face", "vertex"):
        data = raw.get(element, {}).get("data", {})
        # a binary PLY's element is one structured array (its fields are the properties), an
        # ASCII one's a dict of arrays: ask for the names, never compare values
        fields = data.dtype.names or () if isinstance(data, np.ndarray) else tuple(data)
        name = next((n for n in PLY_LABEL_NAMES if n in fields), None)
        if name is not None:
            values = np.asarray(data[name]).reshape(-1)
            labels = values if element == "face" else values[faces[:, 0]]
            break
    if labels is None or len(labels) != len(faces):
        return None
    v = np.asarray(mesh.vertices, np.float64)
    parts = [RawPart(f"seg{int(lab)}", v, faces[labels == lab], is_id=True) for lab in np.unique(labels)]
    return Segmentation(parts, "ply labels")


def find_points_file(path: Path, model_id: str, labels_dir: Path | None) -> tuple[Path, Path] | None:
    """(points, labels) files of a model, if any (see module docstring)."""
    # ShapeNetCore v2 keeps every mesh as <id>/models/model_normalized.obj: the id is the folder's
    shapenet_id = path.parent.parent.name if path.parent.name == "models" else ""
    names = [n for n in dict.fromkeys((path.stem, model_id, shapenet_id)) if n]
    folders = [path.parent, path.parent.parent] + ([Path(labels_dir)] if labels_dir else [])
    for name in names:
        cands = [(path.parent / f"{name}.pts", path.parent / f"{name}.seg")]
        cands += [(d / "points" / f"{name}.pts", d / "points_label" / f"{name}.seg") for d in folders]
        for pts, seg in cands:
            if pts.is_file() and seg.is_file():
                return pts, seg
    return None


def points_segmentation(
    vertices: np.ndarray, faces: np.ndarray, pts_file: Path, seg_file: Path, votes: int = 20000, seed: int = 0
) -> Segmentation:
    """Face labels by majority over ``votes`` surface samples, each taking the label of its
    nearest labelled point (both sets normalized to the unit sphere); a face no sample hit takes
    the label nearest its centre. Voting, not the centre alone: a big triangle's centre can lie
    nearer to the next part's points."""
    try:
        pts = np.loadtxt(pts_file, dtype=np.float64, ndmin=2)[:, :3]
        seg = np.loadtxt(seg_file, dtype=np.int64, ndmin=1).reshape(-1)
    except (OSError, ValueError, IndexError) as exc:
        raise ModelError(pts_file, f"unreadable points/labels file: {exc}") from None
    if len(pts) != len(seg) or not len(pts):
        raise ModelError(seg_file, f"{len(seg)} labels for {len(pts)} points in {pts_file.name}")
    v = np.asarray(vertices, np.float64)
    cm, sm = unit_sphere_transform(v[np.unique(faces)])
    cp, sp = unit_sphere_transform(pts)
    tree = cKDTree(apply_transform(pts, cp, sp))
    nv = apply_transform(v, cm, sm)
    values, seg_ids = np.unique(seg, return_inverse=True)
    _, nearest = tree.query(nv[faces].mean(axis=1))
    face_ids = seg_ids[nearest]
    tri = nv[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if area.sum() > 0:
        rng = np.random.default_rng(seed)
        hit = rng.choice(len(faces), size=votes, p=area / area.sum())
        u, w = rng.random(votes), rng.random(votes)
        flip = u + w > 1
        u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
        t = tri[hit]
        _, near = tree.query(t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + w[:, None] * (t[:, 2] - t[:, 0]))
        tally = np.zeros((len(faces), len(values)), np.int64)
        np.add.at(tally, (hit, seg_ids[near]), 1)
        voted = tally.sum(axis=1) > 0
        face_ids[voted] = tally[voted].argmax(axis=1)
    parts = [RawPart(f"seg{int(values[k])}", v, faces[face_ids == k], is_id=True) for k in np.unique(face_ids)]
    return Segmentation(parts, "points file")


# ---------------------------------------------------------------- part labels of a file source


@dataclass(frozen=True)
class PartLabelSettings:
    """How the prepare stage names a file source's parts: the same reader and map as
    ``python -m train.templates build --source`` (its ``--components``, ``--part-map``,
    ``--labels-dir``), so shard labels and template part names agree."""

    segmentation: bool = setting(True, "False: no part labels (every template part counts as present)")
    part_map: tuple[tuple[str, str | None], ...] = setting((), "read_part_map's entries, in file order")
    labels_dir: str = setting("", "folder with points/<id>.pts + points_label/<id>.seg")

    def key(self) -> dict:
        """What enters the prepare key of a file source: the map by content (a comment or a
        reformatting of the file rebuilds nothing), order kept (the first matching glob wins)."""
        mapping = json.dumps([list(kv) for kv in self.part_map]).encode()
        return {
            "segmentation": self.segmentation,
            "labels_dir": self.labels_dir or None,
            "part_map_sha256": hashlib.sha256(mapping).hexdigest() if self.part_map else None,
        }


@dataclass(frozen=True)
class NamedPart:
    raw: str  # the name in the file (group, node, seg<N>)
    name: str | None  # the common name (normalized, mapped), None: dropped by the map
    vertices: np.ndarray  # source frame
    faces: np.ndarray


def named_parts(
    path: Path, vertices: np.ndarray, faces: np.ndarray, model_id: str, settings: PartLabelSettings
) -> tuple[list[NamedPart], str] | None:
    """A model's parts under their common names, and the segmentation's origin; None when the
    file has no segmentation or the settings turn it off. Names as ``train.templates`` gives
    them (``map_name``; ids such as ``seg3`` keep their digits)."""
    if not settings.segmentation:
        return None
    seg = read_segmentation(
        Path(path), vertices, faces, model_id, Path(settings.labels_dir) if settings.labels_dir else None
    )
    if seg is None:
        return None
    part_map = dict(settings.part_map) or None
    parts = [
        NamedPart(p.name, map_name(p.name, part_map, normalize=not p.is_id), p.vertices, p.faces)
        for p in seg.parts
        if len(p.faces)
    ]
    return parts, seg.origin
