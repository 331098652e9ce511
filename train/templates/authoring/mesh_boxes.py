"""Source meshes → per-model part boxes, as the paper does it: "the bounding box around each
connected component of each segmentation class" (a mesh with no segmentation: each connected
component is one part, all labelled ``part``).

Per model: load (``pipeline.sources.mesh_io.load_mesh``) and normalize like the prepare stage
(bounding-box centre at the origin, farthest vertex at radius 1); split every part into connected
components (vertices welded by position, so triangle soups split by geometry, not by storage);
box each; drop boxes smaller than ``min_part_size`` (largest extent, a fraction of the model's
diameter 2); merge boxes of one label that nearly coincide (the inner and outer shell of a
part, a cushion inside its frame: the smaller lies ``merge_overlap`` inside the larger);
thicken flat boxes to ``min_thickness``; keep the ``max_parts`` largest.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from pipeline.core.errors import ModelError
from pipeline.core.normalize import apply_transform, unit_sphere_transform
from pipeline.core.seeding import rng_for
from pipeline.core.settings_io import setting
from pipeline.sources.mesh_io import load_mesh
from pipeline.sources.part_names import map_name
from pipeline.sources.segmentation import RawPart, read_segmentation
from train.templates.authoring.lattice import Box
from train.templates.authoring.median import sample_surface
from train.templates.authoring.user import ModelBoxes, TemplateInputError

COMPONENT_LABEL = "part"


@dataclass(frozen=True)
class PartSettings:
    min_part_size: float = setting(0.04, "fraction of the model's diameter; smaller components are dropped")
    merge_overlap: float = setting(0.5, "a box this much (of its volume) inside another of its label is merged into it")
    min_thickness: float = setting(0.02, "normalized units: flat parts (one-sided panels) get this depth")
    max_parts: int = setting(32, "boxes kept per model, largest surface first")
    use_segmentation: bool = setting(True, "False: connected components even when the file has labels")
    chamfer_points: int = 2048


def weld_components(vertices: np.ndarray, faces: np.ndarray, digits: int = 6) -> list[np.ndarray]:
    """Face-index arrays of the connected components, vertices equal to ``digits`` decimals joined."""
    if not len(faces):
        return []
    _, vid = np.unique(np.round(vertices, digits), axis=0, return_inverse=True)
    f = vid.reshape(-1)[faces]
    n = int(f.max()) + 1
    rows = np.concatenate([f[:, 0], f[:, 1]])
    cols = np.concatenate([f[:, 1], f[:, 2]])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    face_comp = comp[f[:, 0]]
    order = np.argsort(face_comp, kind="stable")
    splits = np.flatnonzero(np.diff(face_comp[order])) + 1
    return np.split(order, splits)


def _vol(b: Box) -> float:
    return float(np.prod(np.asarray(b.hi) - np.asarray(b.lo)))


def _surface(b: Box) -> float:
    s = np.asarray(b.hi) - np.asarray(b.lo)
    return float(s[0] * s[1] + s[1] * s[2] + s[2] * s[0])


def merge_coincident(boxes: list[Box], overlap: float) -> list[Box]:
    """Merge same-label boxes where the smaller lies at least ``overlap`` of its volume in the
    larger, into their common bounding box, until none is left."""
    out = list(boxes)
    changed = True
    while changed:
        changed = False
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                a, b = out[i], out[j]
                if a.label != b.label:
                    continue
                inter = np.clip(np.minimum(a.hi, b.hi) - np.maximum(a.lo, b.lo), 0, None)
                small = min(_vol(a), _vol(b))
                if small > 0 and np.prod(inter) >= overlap * small:
                    out[i] = Box(a.label, np.minimum(a.lo, b.lo), np.maximum(a.hi, b.hi))
                    del out[j]
                    changed = True
                    break
            if changed:
                break
    return out


def thicken(b: Box, t: float) -> Box:
    """At least ``t`` along every axis, about the box's centre."""
    lo, hi = np.array(b.lo, float), np.array(b.hi, float)
    c, half = (lo + hi) / 2, np.maximum((hi - lo) / 2, t / 2)
    return Box(b.label, c - half, c + half)


def part_boxes(parts: Iterable[tuple[str, np.ndarray, np.ndarray]], settings: PartSettings) -> list[Box]:
    """Boxes of the connected components of each (label, normalized vertices, faces) part."""
    boxes = []
    for label, v, f in parts:
        for comp in weld_components(v, f):
            pts = v[np.unique(f[comp])]
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            if float((hi - lo).max()) >= settings.min_part_size * 2.0:
                boxes.append(Box(label, lo, hi))
    # thicken before merging: a flat panel has no volume to overlap with
    boxes = merge_coincident([thicken(b, settings.min_thickness) for b in boxes], settings.merge_overlap)
    boxes.sort(key=lambda b: (-_surface(b), b.label, tuple(b.lo)))
    return boxes[: settings.max_parts]


def model_boxes(
    path: Path,
    model_id: str,
    settings: PartSettings = PartSettings(),
    seed: int = 0,
    part_map: dict[str, str | None] | None = None,
    labels_dir: Path | None = None,
) -> ModelBoxes:
    """One source mesh → its normalized part boxes and surface samples.

    Raises ModelError (unreadable mesh) or TemplateInputError (no usable parts, a single part)."""
    v, f = load_mesh(path)
    used = v[np.unique(f)]
    center, scale = unit_sphere_transform(used)
    seg = read_segmentation(path, v, f, model_id, labels_dir) if settings.use_segmentation else None
    raw: list[RawPart] = seg.parts if seg is not None else [RawPart(COMPONENT_LABEL, v, f, is_id=True)]
    parts = []
    for p in raw:
        name = map_name(p.name, part_map, normalize=not p.is_id) if seg is not None else COMPONENT_LABEL
        if name is not None and len(p.faces):
            parts.append((name, apply_transform(p.vertices, center, scale), p.faces))
    boxes = part_boxes(parts, settings)
    origin = seg.origin if seg is not None else "connected components"
    if not boxes:
        raise TemplateInputError(
            f"{path}: no usable parts ({origin}: every part is under --min-part-size "
            f"{settings.min_part_size} of the model's size or dropped by the part map)"
        )
    if len(boxes) == 1:
        raise TemplateInputError(
            f"{path}: one part ({boxes[0].label!r}, from {origin}) spans the whole model, so the template would be "
            "a single box; give a segmentation (OBJ groups, glTF nodes, PLY labels, a .pts/.seg file), lower "
            "--min-part-size, or write a --cuboids file"
        )
    rng = rng_for(seed, "templates", "user", model_id)
    cloud = sample_surface(apply_transform(v, center, scale), f, settings.chamfer_points, rng)
    return ModelBoxes(model_id, boxes, cloud, set(), origin)


def source_models(
    source: str,
    category: str,
    settings: PartSettings = PartSettings(),
    seed: int = 0,
    limit: int | None = None,
    part_map: dict[str, str | None] | None = None,
    labels_dir: Path | None = None,
    strict: bool = False,
    progress: Callable[[int, str], None] | None = None,
) -> tuple[list[ModelBoxes], dict[str, str]]:
    """The part boxes of every model of ``category`` in a pipeline source (any layout the
    pipeline lists), and {model id: why it was skipped}; ``strict``: raise at the first bad model."""
    from pipeline.sources.layouts import iter_models, list_categories

    refs = list(iter_models(source, category))
    if limit is not None:
        refs = refs[:limit]
    if not refs:
        raise TemplateInputError(
            f"{source}: no models of category {category!r} "
            f"(categories there: {', '.join(list_categories(source)) or 'none'})"
        )
    models, failures = [], {}
    for n, ref in enumerate(refs):
        try:
            models.append(model_boxes(Path(ref.path), ref.model_id, settings, seed, part_map, labels_dir))
        except (ModelError, TemplateInputError) as exc:
            if strict:
                raise TemplateInputError(f"model {ref.model_id}: {exc}") from exc
            failures[ref.model_id] = str(exc)
        if progress:
            progress(n + 1, ref.model_id)
    if not models:
        raise TemplateInputError(f"{category}: no usable model; " + "; ".join(f"{k}: {v}" for k, v in failures.items()))
    return models, failures
