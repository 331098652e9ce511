"""Geometric and topological checks of a template's initial geometry.

``conforming_mesh`` triangulates every patch as a fan around its centre over its boundary
polygon — corners plus the junction points lying on its curves — so patches meeting at
T-junctions share vertices exactly and the welded result can be tested for watertightness.
The fan is exact for planar convex patches (templates built from cuboids); for curved patches it
is a coarse approximation used only for topology.

Checks run on one on/off combination of optional parts: ``active`` patch ids, by default
``tpl.active_patches()`` (every part present, closing patches left out).
"""

from __future__ import annotations

import numpy as np
import torch

from train.geometry.intersections import triangles_intersect
from train.templates.template import JunctionPoint, Template


def _active(tpl: Template, active: list[int] | None) -> list[int]:
    return tpl.active_patches() if active is None else list(active)


def part_combinations(tpl: Template) -> list[dict[str, bool]]:
    """Every on/off combination of the template's optional parts (all present first)."""
    names = tpl.part_names
    return [{n: not (m >> b) & 1 for b, n in enumerate(names)} for m in range(2 ** len(names))]


def point_positions(tpl: Template) -> np.ndarray:
    with torch.no_grad():
        return tpl.points_from_params(tpl.initial_params(torch.float64))[0].numpy()


def patch_polygons(tpl: Template, active: list[int] | None = None) -> list[list[int]]:
    """Per active patch, its boundary point ids in order (P00 → P10 → P11 → P01, junctions inserted)."""
    on_curve: dict[int, list[tuple[float, int]]] = {}
    for i, p in enumerate(tpl.points):
        if isinstance(p, JunctionPoint):
            on_curve.setdefault(p.curve, []).append((p.t, i))
    polys = []
    for pi in _active(tpl, active):
        patch = tpl.patches[pi]
        poly: list[int] = []
        for c, rev in zip(patch.curves, patch.reverse):
            seq = _curve_points(tpl, c, on_curve)
            if rev:
                seq = seq[::-1]
            poly.extend(seq[:-1])
        polys.append(poly)
    return polys


def _curve_points(tpl: Template, c: int, on_curve: dict[int, list[tuple[float, int]]]) -> list[int]:
    """End points and the junction points inside curve ``c``, in curve order (sub-curves included)."""
    cur = tpl.curves[c]
    if not cur.is_sub:
        a, b = cur.points[0], cur.points[3]
        return [a] + [i for _, i in sorted(on_curve.get(c, []))] + [b]
    parent = _curve_points(tpl, cur.parent, on_curve)
    i, j = parent.index(cur.start), parent.index(cur.end)
    return parent[i : j + 1] if i <= j else parent[j : i + 1][::-1]


def conforming_mesh(tpl: Template, active: list[int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (template points, then one centre per active patch), faces, each face's patch id."""
    pos = point_positions(tpl)
    ids = _active(tpl, active)
    polys = patch_polygons(tpl, ids)
    verts = [pos]
    faces, owner = [], []
    n = len(pos)
    for k_poly, (pi, poly) in enumerate(zip(ids, polys)):
        centre = pos[poly].mean(axis=0)
        verts.append(centre[None])
        c = n + k_poly
        for k in range(len(poly)):
            faces.append((c, poly[k], poly[(k + 1) % len(poly)]))
            owner.append(pi)
    return np.concatenate(verts), np.array(faces, np.int64), np.array(owner, np.int64)


def closed_manifold_problems(tpl: Template, active: list[int] | None = None) -> list[str]:
    """Empty when every boundary edge is used once in each direction and each vertex's fan is one disk."""
    problems = []
    polys = patch_polygons(tpl, active)
    directed: dict[tuple[int, int], int] = {}
    for poly in polys:
        for k in range(len(poly)):
            e = (poly[k], poly[(k + 1) % len(poly)])
            directed[e] = directed.get(e, 0) + 1
    for (a, b), n in sorted(directed.items()):
        if n != 1 or directed.get((b, a), 0) != 1:
            problems.append(f"edge {a}-{b} used {n}x forward, {directed.get((b, a), 0)}x backward")
    # Vertex links: the edges (prev → next) around each point must form a single cycle.
    link: dict[int, dict[int, int]] = {}
    for poly in polys:
        m = len(poly)
        for k in range(m):
            v, prev, nxt = poly[k], poly[k - 1], poly[(k + 1) % m]
            link.setdefault(v, {})[nxt] = prev
    for v, nxt in link.items():
        start = next(iter(nxt))
        cur, steps = start, 0
        while cur in nxt and steps <= len(nxt):
            cur = nxt[cur]
            steps += 1
            if cur == start:
                break
        if cur != start or steps != len(nxt):
            problems.append(f"point {v}: patches around it do not form one disk")
    return problems


def euler_characteristic(tpl: Template, active: list[int] | None = None) -> int:
    v, f, _ = conforming_mesh(tpl, active)
    edges = {
        tuple(sorted((int(a), int(b)))) for tri in f for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0]))
    }
    return len(np.unique(f)) - len(edges) + len(f)


def junction_errors(tpl: Template) -> np.ndarray:
    """Distance of each junction point's stored position from its parent curve at its t."""
    from train.geometry.bezier import bezier_eval

    with torch.no_grad():
        params = tpl.initial_params(torch.float64)[None]
        pts, ctrl = tpl._evaluate(params)
    errs = []
    for i, p in enumerate(tpl.points):
        if isinstance(p, JunctionPoint):
            on = bezier_eval(ctrl[0, p.curve], torch.tensor([p.t], dtype=torch.float64))[0]
            errs.append(float(torch.linalg.norm(on - pts[0, i])))
    return np.array(errs)


def self_intersections(tpl: Template, tol: float = 1e-9, active: list[int] | None = None) -> list[tuple[int, int]]:
    """Pairs of non-adjacent active patches whose triangles touch or cross (edge–triangle piercing)."""
    verts, faces, owner = conforming_mesh(tpl, active)
    adjacent = set(tpl.adjacency())
    tri = verts[faces]  # (F, 3, 3)
    lo, hi = tri.min(1) - tol, tri.max(1) + tol
    found: set[tuple[int, int]] = set()
    for i in range(len(tri)):
        cand = np.nonzero(np.all(hi[i] >= lo, axis=1) & np.all(lo[i] <= hi, axis=1) & (owner > owner[i]))[0]
        cand = [j for j in cand if (owner[i], owner[j]) not in adjacent and (owner[i], owner[j]) not in found]
        if not cand:
            continue
        cand = np.array(cand)
        hit = triangles_intersect(tri[i][None], tri[cand], tol)
        for j in cand[hit]:
            found.add((int(owner[i]), int(owner[j])))
    return sorted(found)


def surface_components(tpl: Template, active: list[int] | None = None) -> int:
    """Number of connected pieces of the active patches (patches touching at a curve or point)."""
    ids = _active(tpl, active)
    root = {i: i for i in ids}

    def find(i: int) -> int:
        while root[i] != i:
            root[i] = root[root[i]]
            i = root[i]
        return i

    for i, j in tpl.adjacency():
        if i in root and j in root:
            root[find(i)] = find(j)
    return len({find(i) for i in ids})
