"""Part family of every surface sample, from the procedural source's per-part OBJ groups.

The prepared mesh is a repaired union, so it has lost which face came from which part; the source
OBJ still has one ``o <label>`` group per part. Each part is sampled densely in the normalized
frame and a surface point takes the family of the nearest part sample.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from pipeline.core.errors import ModelError
from pipeline.core.normalize import apply_transform
from pipeline.core.schema import part_family
from pipeline.prepare.sampling import sample_surface

SAMPLES_PER_PART = 4096


def read_obj_parts(path: Path) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(label, vertices, faces) per ``o`` group of an OBJ whose faces are triangles (the
    procedural writer's format); face indices are made local to their group."""
    groups: list[tuple[str, list, list]] = []
    verts: list[list[float]] = []
    try:
        lines = Path(path).read_text().splitlines()
    except OSError as e:
        raise ModelError(path, f"cannot read source OBJ: {e.strerror or e}") from e
    for line in lines:
        head, _, rest = line.partition(" ")
        if head == "o":
            groups.append((rest.strip(), [], []))
        elif head == "v":
            verts.append([float(x) for x in rest.split()[:3]])
        elif head == "f" and groups:
            groups[-1][2].append([int(x.split("/")[0]) - 1 for x in rest.split()[:3]])
    all_v = np.asarray(verts, np.float64).reshape(-1, 3)
    out = []
    for label, _, faces in groups:
        f = np.asarray(faces, np.int64).reshape(-1, 3)
        if not len(f):
            continue
        used, local = np.unique(f, return_inverse=True)
        out.append((label, all_v[used], local.reshape(-1, 3)))
    return out


def label_points(
    points: np.ndarray, parts: list[tuple[str, np.ndarray, np.ndarray]], center, scale: float, rng: np.random.Generator
) -> tuple[np.ndarray, list[str]]:
    """uint8 ``(N,)`` family index per point (xyz in the normalized frame) and the sorted family names."""
    names = sorted({part_family(label) for label, _, _ in parts})
    if len(names) > 255:
        raise ValueError(f"{len(names)} part families do not fit uint8 labels")
    samples, ids = [], []
    for label, v, f in parts:
        mesh = trimesh.Trimesh(apply_transform(v, np.asarray(center, float), float(scale)), f, process=False)
        if mesh.area <= 0:
            continue
        samples.append(sample_surface(mesh, SAMPLES_PER_PART, rng)[:, :3])
        ids.append(np.full(SAMPLES_PER_PART, names.index(part_family(label)), np.uint8))
    if not samples:
        raise ValueError("no part has a surface")
    _, nearest = cKDTree(np.concatenate(samples)).query(np.asarray(points)[:, :3], k=1)
    return np.concatenate(ids)[nearest], names


def source_obj(prepare_dir: Path, rec: dict) -> Path | None:
    """The procedural source OBJ of a prepared model, found under the same work folder (the path in
    the record is relative to wherever the build ran); None when the source has no part groups."""
    src = rec.get("source")
    if not isinstance(src, dict) or src.get("kind") != "procedural" or not src.get("path"):
        return None
    rel = Path(src["path"])
    work = Path(prepare_dir).parents[2]  # <work>/prepare-<hash>/<category>/<model_id>
    for cand in (work.joinpath(*rel.parts[-3:]), rel):
        if cand.is_file():
            return cand
    raise ModelError(prepare_dir, f"procedural source {rel} not found (needed for per-point part labels)")
