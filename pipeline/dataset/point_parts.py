"""Part family of every shard point.

Procedural source: from its per-part OBJ groups (one ``o <label>`` group per part), labelled here
(``procedural_point_parts``). File source: the prepare stage labelled its samples from the
segmentation (``pipeline.prepare.part_labels``); here they are only subsampled with the points
(``prepared_point_parts``). Either way: uint8 ids into sorted family names.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.core.errors import ModelError
from pipeline.core.schema import part_family
from pipeline.prepare.part_labels import SAMPLES_PER_PART, label_points

__all__ = [
    "SAMPLES_PER_PART",
    "label_points",
    "prepared_point_parts",
    "procedural_point_parts",
    "read_obj_parts",
    "source_obj",
]


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


def procedural_point_parts(
    obj: Path, points: np.ndarray, center, scale: float, rng: np.random.Generator
) -> tuple[np.ndarray, list[str]]:
    """Family ids of ``points`` (normalized frame) from a procedural OBJ's part groups."""
    parts = [(part_family(label), v, f) for label, v, f in read_obj_parts(obj)]
    return label_points(points, parts, center, scale, rng)


def prepared_point_parts(prepare_dir: Path, rec: dict, idx: np.ndarray | None) -> tuple[np.ndarray, list[str]] | None:
    """The prepare stage's sample labels of a file source model, at the shard's subset ``idx``
    of the samples (None: all), and their names; None when prepare labelled none."""
    info = rec.get("part_labels")
    name = (rec.get("files") or {}).get("sample_parts")
    if not isinstance(info, dict) or not name:
        return None
    path = Path(prepare_dir) / name
    try:
        ids = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise ModelError(path, f"cannot load sample part labels: {e}") from e
    names = list(info.get("names") or [])
    if ids.ndim != 1 or ids.dtype != np.uint8 or (len(ids) and int(ids.max()) >= len(names)):
        raise ModelError(path, f"sample part labels must be uint8 (N,) ids into {len(names)} names")
    if idx is not None:
        ids = ids[idx]
    return np.ascontiguousarray(ids), names
