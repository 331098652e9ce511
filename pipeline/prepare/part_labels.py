"""Which part each surface sample belongs to, from the source's part meshes.

The prepared mesh is a repaired union, so it has lost which face came from which part; the source
still has its parts (the procedural OBJ's ``o`` groups, a file source's segmentation). Each part is
sampled densely in the normalized frame and a point takes the name of the nearest part sample.

File sources are labelled here, at prepare, where the source mesh is already loaded and the
segmentation settings are known (``sample_parts.npy`` beside ``samples.npy``); the shard writer
only subsamples those labels. Procedural sources are labelled by the shard writer
(``pipeline.dataset.point_parts``), as before.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from pipeline.core.normalize import apply_transform
from pipeline.prepare.sampling import sample_surface
from pipeline.sources.segmentation import PartLabelSettings, named_parts

SAMPLES_PER_PART = 4096
# A file source can have hundreds of groups (one per object of a scene export): the part samples
# of one model are capped at this many in all, at least MIN_SAMPLES_PER_PART each.
MAX_PART_SAMPLES = 32 * SAMPLES_PER_PART
MIN_SAMPLES_PER_PART = 256


def label_points(
    points: np.ndarray,
    parts: list[tuple[str, np.ndarray, np.ndarray]],
    center,
    scale: float,
    rng: np.random.Generator,
    per_part: int = SAMPLES_PER_PART,
) -> tuple[np.ndarray, list[str]]:
    """uint8 ``(N,)`` name index per point (xyz in the normalized frame) and the sorted names.

    ``parts``: (name, vertices, faces) in the source frame; parts sharing a name share a label
    (the caller has already reduced labels to families)."""
    names = sorted({name for name, _, _ in parts})
    if len(names) > 255:
        raise ValueError(f"{len(names)} part families do not fit uint8 labels")
    samples, ids = [], []
    for name, v, f in parts:
        mesh = trimesh.Trimesh(apply_transform(v, np.asarray(center, float), float(scale)), f, process=False)
        if mesh.area <= 0:
            continue
        samples.append(sample_surface(mesh, per_part, rng)[:, :3])
        ids.append(np.full(per_part, names.index(name), np.uint8))
    if not samples:
        raise ValueError("no part has a surface")
    _, nearest = cKDTree(np.concatenate(samples)).query(np.asarray(points)[:, :3], k=1)
    return np.concatenate(ids)[nearest], names


def segmentation_labels(
    path: Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    model_id: str,
    settings: PartLabelSettings,
    samples: np.ndarray,
    center,
    scale: float,
    rng: np.random.Generator,
) -> tuple[dict, np.ndarray] | None:
    """A file source model's record fields (``parts``, ``part_labels``) and the uint8 label of
    each of its ``samples``; None when it has no segmentation or the map drops every part.

    A point takes the name of the nearest kept part: points of a dropped part (``screw*: null``)
    go to their neighbour, as the template, which has no box for them, sees them."""
    found = named_parts(path, vertices, faces, model_id, settings)
    if found is None:
        return None
    parts, origin = found
    kept = [(p.name, *_local(p.vertices, p.faces)) for p in parts if p.name is not None]
    if not kept:
        return None
    per_part = max(MIN_SAMPLES_PER_PART, min(SAMPLES_PER_PART, MAX_PART_SAMPLES // len(kept)))
    try:
        ids, names = label_points(samples, kept, center, scale, rng, per_part)
    except ValueError:  # no kept part has area, or over 255 names: no labels rather than a failed model
        return None
    fields = {
        "parts": [{"label": p.raw, "family": p.name, "n_faces": int(len(p.faces))} for p in parts],
        "part_labels": {"origin": origin, "names": names},
    }
    return fields, ids


def _local(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A part's own vertices (the segmentation readers share the whole mesh's among its parts,
    which would be transformed once per part)."""
    used, local = np.unique(faces, return_inverse=True)
    return vertices[used], local.reshape(-1, 3)
