"""A deformable Coons-patch template from a collection of labelled cuboids.

cuboids → (normalize) → lattice quad mesh (lattice.py) → greedy merge (merge.py) → Template:
each merged rectangle becomes a patch whose sides are straight cubic Bézier curves (interior
control points at 1/3 and 2/3); equal sides are one shared curve, a side lying inside a longer
side across from it is a junction sub-curve of that parent, and a corner strictly inside a side
is a junction point on it (parameter t along the straight, uniformly parameterized parent).

Optional labels (airplane engines) give optional patches (present with the part) and closing
patches (present without it, sealing the body where the part was attached), so every on/off
combination of optional parts is a closed surface, as in the paper's turbine case.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pipeline.core.normalize import apply_transform, unit_sphere_transform
from pipeline.core.settings_io import setting
from train.templates.authoring.lattice import Box, CuboidLike, Lattice, boundary_quads, build_lattice, mirrored_boxes
from train.templates.authoring.merge import PatchSet, Rect, _rect_key, merge_quads
from train.templates.template import Curve, FreePoint, JunctionPoint, Patch, Template


@dataclass(frozen=True)
class TemplateSettings:
    snap_tol: float = setting(0.01, "grid lines closer than this (normalized units) are snapped together")
    symmetric: bool = setting(True, "mirror the cuboids across x = 0 and merge in mirror pairs")
    declare_symmetry: bool = setting(True, "store the plane and point pairs (the symmetry loss uses them)")
    optional_labels: tuple[str, ...] = ("turbine", "engine")
    # part groups with separate loss terms: group name -> labels; unlisted labels form "body"
    part_groups: tuple[tuple[str, tuple[str, ...]], ...] = ()


def normalize_boxes(boxes: Sequence[CuboidLike], center: np.ndarray, scale: float) -> list[Box]:
    """Apply the prepare stage's normalization x → (x - center) / scale to every box."""
    return [Box(b.label, apply_transform(b.lo, center, scale), apply_transform(b.hi, center, scale)) for b in boxes]


def box_normalization(boxes: Sequence[CuboidLike]) -> tuple[np.ndarray, float]:
    """(centre, scale) putting the boxes' bbox centre at the origin and farthest corner at 1."""
    corners = np.array(
        [[x, y, z] for b in boxes for x in (b.lo[0], b.hi[0]) for y in (b.lo[1], b.hi[1]) for z in (b.lo[2], b.hi[2])]
    )
    return unit_sphere_transform(corners)


def patch_set_from_boxes(
    boxes: Sequence[CuboidLike], settings: TemplateSettings = TemplateSettings()
) -> tuple[PatchSet, Lattice]:
    """Lattice quad mesh of the union merged into rectangles, and the lattice (normalized boxes)."""
    if settings.symmetric:
        boxes = mirrored_boxes(boxes)
    present = {b.label for b in boxes}
    optional = tuple(lab for lab in settings.optional_labels if lab in present)
    lattice = build_lattice(boxes, settings.snap_tol, symmetric_x=settings.symmetric, optional=optional)
    return merge_quads(boundary_quads(lattice), mirror=settings.symmetric), lattice


def template_from_boxes(
    boxes: Sequence[CuboidLike],
    name: str = "",
    settings: TemplateSettings = TemplateSettings(),
    metadata: dict | None = None,
) -> Template:
    """Build a Template from normalized ``boxes`` (see ``normalize_boxes``)."""
    ps, lattice = patch_set_from_boxes(boxes, settings)
    labels = lattice.labels
    tpl = template_from_patch_set(ps, labels, name=name, optional_labels=settings.optional_labels)
    tpl = dataclasses.replace(
        tpl,
        part_groups=part_groups(tpl.patch_labels, settings.part_groups),
        metadata={
            "construction": "cuboids",
            "lattice_lines": [len(ln) for ln in lattice.lines],
            "filled_cells": int(lattice.filled),
            "snap_tol": settings.snap_tol,
            **(metadata or {}),
        },
    )
    if settings.symmetric and settings.declare_symmetry:
        tpl = tpl.with_symmetry(0.0, tol=1e-6)
    return tpl


def template_from_patch_set(
    ps: PatchSet, labels: list[str], name: str = "", optional_labels: Sequence[str] = ()
) -> Template:
    lines = ps.lines
    rects: list[Rect] = sorted(ps.rects.values(), key=_rect_key)

    def world(p: tuple[int, int, int]) -> tuple[float, float, float]:
        return (float(lines[0][p[0]]), float(lines[1][p[1]]), float(lines[2][p[2]]))

    # Distinct sides, and which ones are sub-curves of a longer side across the line.
    sides = sorted({s for r in rects for s in r.sides()})
    by_line: dict[tuple, list[tuple[int, int]]] = {}
    for line, lo, hi in sides:
        by_line.setdefault(line, []).append((lo, hi))
    parent_of: dict[tuple, tuple] = {}
    for line, lo, hi in sides:
        for l2, h2 in by_line[line]:
            if l2 <= lo and hi <= h2 and (l2, h2) != (lo, hi):
                parent_of[(line, lo, hi)] = (line, l2, h2)
    regular = [s for s in sides if s not in parent_of]
    children = [s for s in sides if s in parent_of]
    curve_id = {s: i for i, s in enumerate(regular + children)}

    # Corner points: junction points when strictly inside a regular side.
    corners = sorted({p for r in rects for p in r.corners()})
    point_id = {p: i for i, p in enumerate(corners)}
    points: list[FreePoint | JunctionPoint] = []
    for p in corners:
        host = None
        for d in range(3):
            key = list(p)
            key[d] = -1
            for lo, hi in by_line.get((d, *key), ()):
                s = ((d, *key), lo, hi)
                if s in curve_id and s not in parent_of and lo < p[d] < hi:
                    host = (s, d, lo, hi)
        if host is None:
            points.append(FreePoint(world(p)))
        else:
            s, d, lo, hi = host
            t = (lines[d][p[d]] - lines[d][lo]) / (lines[d][hi] - lines[d][lo])
            points.append(JunctionPoint(curve_id[s], float(t)))

    curves: list[Curve] = []
    for s in regular:
        line, lo, hi = s
        a, b = np.array(world(_pt(line, lo))), np.array(world(_pt(line, hi)))
        inner = []
        for f in (1.0 / 3.0, 2.0 / 3.0):
            inner.append(len(points))
            points.append(FreePoint(tuple(float(x) for x in a + f * (b - a))))
        curves.append(Curve(points=(point_id[_pt(line, lo)], inner[0], inner[1], point_id[_pt(line, hi)])))
    for s in children:
        line, lo, hi = s
        curves.append(Curve(parent=curve_id[parent_of[s]], start=point_id[_pt(line, lo)], end=point_id[_pt(line, hi)]))

    patches: list[Patch] = []
    for r in rects:
        cs = r.corners()
        cids, rev = [], []
        for k in range(4):
            p, q = cs[k], cs[(k + 1) % 4]
            d = next(a for a in range(3) if p[a] != q[a])
            key = list(p)
            key[d] = -1
            lo, hi = min(p[d], q[d]), max(p[d], q[d])
            cids.append(curve_id[((d, *key), lo, hi)])
            rev.append(p[d] > q[d])
        patches.append(Patch(tuple(cids), tuple(rev), labels[r.label]))
    optional = {
        lab: [i for i, p in enumerate(patches) if p.label == lab]
        for lab in sorted(set(optional_labels))
        if any(p.label == lab for p in patches)
    }
    closing: dict[str, list[int]] = {}
    for i, r in enumerate(rects):
        if r.neg >= 0:
            closing.setdefault(labels[r.neg], []).append(i)
    return Template(
        points=points,
        curves=curves,
        patches=patches,
        name=name,
        optional_parts=optional,
        closing_patches=dict(sorted(closing.items())),
    )


def part_groups(labels: list[str], groups: Sequence[tuple[str, Sequence[str]]]) -> dict[str, list[str]]:
    """Patch labels per group (``groups``: name → labels), keeping the labels the template has;
    labels in no group form one more group in the loss."""
    have = set(labels)
    out = {name: sorted(lab for lab in labs if lab in have) for name, labs in groups}
    return {name: labs for name, labs in sorted(out.items()) if labs}


def _pt(line: tuple, t: int) -> tuple[int, int, int]:
    p = list(line[1:])
    p[line[0]] = t
    return tuple(p)  # type: ignore[return-value]
