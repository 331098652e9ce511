"""The "embree" contour backend: visible feature edges of a triangle mesh by ray casting, no Blender.

Draws the same lines as the Freestyle backend (render.scene) from plain numpy and the Embree ray
engine (``embreex``): per mesh, the faces' normals, the edges between adjacent faces with their
dihedral angles, and one ray-tracing BVH; per view,

1. feature edges: silhouettes (the two faces of the edge face the camera differently), borders
   (edges of one face) and creases (normals more than ``180° − crease_angle_deg`` apart: the
   same convention as Freestyle's crease angle), those of the kinds in ``edge_types``;
2. about one sample per pixel along each projected edge, each tested for visibility with one
   occlusion ray from the camera that stops just short of the sample;
3. runs of visible samples chained into polylines through the mesh vertices they share, then
   joined across small gaps like Freestyle's captured fragments (render.join);
4. the polylines drawn anti-aliased, ``line_thickness`` px wide, black on white.

Strokes come out in the strokes.json format (render.capture): pixel (u, v) from the top-left,
``type`` the edge nature under most points. Same mesh and view give the same bytes: all steps
are serial and ordered by edge index.
"""

from __future__ import annotations

import math

import numpy as np

from render.cameras import View
from render.capture import typed_stroke
from render.settings import EMBREE_SILHOUETTE_TYPES, RenderSettings

# Edge natures, in Freestyle's precedence when an edge has several (capture._TYPE_ORDER).
SILHOUETTE, BORDER, CREASE = 0, 1, 2
NATURE_NAMES = ("silhouette", "border", "crease")

_VISIBLE_SLACK = 2e-3  # occlusion rays stop this fraction short of the sample (depth precision)


class MeshLines:
    """A mesh ready for per-view line drawing: adjacency, creases, borders and the ray BVH."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, settings: RenderSettings) -> None:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.settings = settings
        self.vertices = np.ascontiguousarray(vertices, np.float64)
        self.faces = np.ascontiguousarray(faces, np.int64)
        tri = self.vertices[self.faces]
        normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(normals, axis=1)
        keep = length > 0  # degenerate faces have no side to face the camera with
        self.normals = np.where(keep[:, None], normals / np.where(length > 0, length, 1.0)[:, None], 0.0)
        self.centers = tri.mean(axis=1)
        self.face_pairs, self.pair_edges, border = _edge_topology(self.faces[keep], np.flatnonzero(keep))
        cos_pair = np.einsum("ij,ij->i", self.normals[self.face_pairs[:, 0]], self.normals[self.face_pairs[:, 1]])
        crease_cos = math.cos(math.radians(180.0 - settings.crease_angle_deg))
        kinds = set(settings.edge_types)
        self.draw_silhouettes = bool(kinds & set(EMBREE_SILHOUETTE_TYPES))
        self.crease = (cos_pair < crease_cos) & ("crease" in kinds)
        self.border_edges = border if "border" in kinds else border[:0]
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene=self._scene, vertices=self.vertices.astype(np.float32), indices=self.faces.astype(np.int32))

    def feature_edges(self, view: View) -> tuple[np.ndarray, np.ndarray]:
        """(m,2) vertex ids of this view's silhouette, border and crease edges and their natures."""
        if view.orthographic:
            toward_eye = -view.world_to_camera[2, :3]  # every ray has the camera's forward direction
            front = self.normals @ toward_eye > 0
        else:
            front = np.einsum("ij,ij->i", self.normals, view.eye - self.centers) > 0
        sil = (front[self.face_pairs[:, 0]] != front[self.face_pairs[:, 1]]) & self.draw_silhouettes
        pair = sil | self.crease
        edges = np.concatenate([self.pair_edges[pair], self.border_edges])
        nature = np.concatenate([np.where(sil[pair], SILHOUETTE, CREASE), np.full(len(self.border_edges), BORDER)])
        return edges, nature

    def visible(self, view: View, points: np.ndarray) -> np.ndarray:
        """Is each world point seen by the camera (no surface in front of it)?"""
        if view.orthographic:
            forward = view.world_to_camera[2, :3]
            dirs = np.broadcast_to(forward, points.shape)
            # start every ray on a plane well outside the unit sphere the model lies in
            dist = points @ forward + view.distance
            origins = points - dist[:, None] * forward
        else:
            origins = np.broadcast_to(view.eye, points.shape)
            delta = points - view.eye
            dist = np.linalg.norm(delta, axis=1)
            dirs = delta / dist[:, None]
        hit = self._scene.run(
            np.ascontiguousarray(origins, np.float32),
            np.ascontiguousarray(dirs, np.float32),
            dists=(dist * (1.0 - _VISIBLE_SLACK)).astype(np.float32),
            query="OCCLUDED",
        )
        return np.asarray(hit) == -1

    def strokes(self, view: View) -> list[dict]:
        """The view's visible lines as strokes.json entries (points rounded to 1e-4 px)."""
        s = self.settings
        edges, nature = self.feature_edges(view)
        if len(edges) == 0:
            return []
        from render.cameras import project

        a, b = edges[:, 0], edges[:, 1]
        uv_ab = project(view.projection, self.vertices[edges.ravel()]).reshape(-1, 2, 2)
        n_seg = np.maximum(1, np.ceil(np.linalg.norm(uv_ab[:, 1] - uv_ab[:, 0], axis=1)).astype(np.int64))
        start = np.concatenate([[0], np.cumsum(n_seg + 1)])
        edge_of = np.repeat(np.arange(len(edges)), n_seg + 1)
        t = (np.arange(start[-1]) - start[edge_of]) / n_seg[edge_of]
        pts = self.vertices[a][edge_of] * (1.0 - t)[:, None] + self.vertices[b][edge_of] * t[:, None]
        # edges meeting at a vertex sample it once each: cast one ray per vertex
        at_vertex = (t == 0.0) | (t == 1.0)
        vid = np.where(t == 0.0, a[edge_of], b[edge_of])[at_vertex]
        uniq, inv = np.unique(vid, return_inverse=True)
        inner = np.flatnonzero(~at_vertex)
        hits = self.visible(view, np.concatenate([self.vertices[uniq], pts[inner]]))
        seen = np.empty(len(pts), bool)
        seen[at_vertex] = hits[: len(uniq)][inv]
        seen[inner] = hits[len(uniq) :]
        uv = project(view.projection, pts)
        chains = _chain(edges, nature, start, seen, uv, s.join_gap_px)
        if s.min_stroke_px > 0:
            chains = [c for c in chains if _length(c[0]) >= s.min_stroke_px]
        if not chains:
            return []
        # rounded and typed in one go: points per nature per stroke from a cumulative count
        sizes = np.array([len(p) for p, _ in chains])
        flat = np.round(np.concatenate([p for p, _ in chains]), 4).tolist()
        kinds = np.concatenate([k for _, k in chains])
        ends = np.cumsum(sizes)
        counts = np.diff(
            np.vstack([np.zeros(3, np.int64), np.cumsum(kinds[:, None] == np.arange(3), axis=0)[ends - 1]]), axis=0
        ).tolist()
        return [
            typed_stroke(flat[e - n : e], {NATURE_NAMES[k]: c for k, c in enumerate(cnt) if c})
            for e, n, cnt in zip(ends.tolist(), sizes.tolist(), counts)
        ]

    def draw(self, view: View) -> tuple[np.ndarray, list[dict]]:
        """The view's drawing (uint8 gray, black lines on white) and its strokes."""
        strokes = self.strokes(view)
        return draw_strokes(
            [np.asarray(st["points"]) for st in strokes], self.settings.image_size, self.settings.line_thickness
        ), strokes


def _edge_topology(faces: np.ndarray, face_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs of faces sharing an edge (edges of exactly two faces), those edges, and border edges
    (one face). Edges of three or more faces (non-manifold) pair their faces in index order."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    code = e[:, 0] * (int(faces.max(initial=0)) + 1) + e[:, 1]
    owner = np.repeat(face_ids[None], 3, axis=0).ravel()
    order = np.argsort(code, kind="stable")  # stable: faces of one edge stay in index order
    code, e, owner = code[order], e[order], owner[order]
    new = np.concatenate(([True], code[1:] != code[:-1]))
    single = new & np.concatenate((new[1:], [True]))
    # consecutive members of one edge's group form its pairs (a manifold edge: exactly one pair)
    same = ~new[1:]
    pairs = np.stack([owner[:-1][same], owner[1:][same]], axis=1)
    return pairs, e[1:][same], e[single]


def _runs(edges: np.ndarray, start: np.ndarray, seen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last sample index of every run of two or more consecutive visible samples
    within one edge."""
    edge_of = np.repeat(np.arange(len(edges)), np.diff(start))
    last_of_edge = np.concatenate((edge_of[1:] != edge_of[:-1], [True]))
    first_of_edge = np.concatenate(([True], last_of_edge[:-1]))
    run_start = np.flatnonzero(seen & (first_of_edge | ~np.concatenate(([True], seen[:-1]))))
    # a run ends at the first hidden sample after its start (exclusive) or its edge's last sample
    stop = np.flatnonzero(~seen | last_of_edge)
    k = stop[np.searchsorted(stop, run_start)]
    run_end = np.where(seen[k], k, k - 1)
    long = run_end > run_start
    return run_start[long], run_end[long]


def _chain(
    edges: np.ndarray,
    nature: np.ndarray,
    start: np.ndarray,
    seen: np.ndarray,
    uv: np.ndarray,
    gap_px: float,
    max_turn_deg: float = 60.0,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Runs of visible samples chained end to end into polylines: (points, natures per point).

    Run ends meet where edges share a mesh vertex (same point) or, like Freestyle's captured
    fragments (render.join), across a gap of at most ``gap_px`` if the line turns by no more than
    ``max_turn_deg`` there. Each end is used once, best pairs first (closest, then straightest),
    ties broken by index, so the result is deterministic.
    """
    run_start, run_end = _runs(edges, start, seen)
    n = len(run_start)
    if n == 0:
        return []
    edge_of_run = np.searchsorted(start, run_start, side="right") - 1
    # end 2r is run r's first sample, 2r+1 its last; out-direction points away from the run
    end_idx = np.stack([run_start, run_end], axis=1).ravel()
    inner_idx = np.stack([run_start + 1, run_end - 1], axis=1).ravel()
    end_uv = uv[end_idx]
    out_dir = end_uv - uv[inner_idx]
    out_dir /= np.maximum(np.linalg.norm(out_dir, axis=1), 1e-12)[:, None]
    # an end at its edge's first/last sample sits on that mesh vertex; others inside the edge
    e = edge_of_run
    vert = np.stack(
        [np.where(run_start == start[e], edges[e, 0], -1), np.where(run_end == start[e + 1] - 1, edges[e, 1], -1)],
        axis=1,
    ).ravel()
    link = np.full(2 * n, -1, np.int64)
    # ends sharing a vertex: pairs meet at once; three or more pair up straightest first
    on_v = np.flatnonzero(vert >= 0)
    on_v = on_v[np.argsort(vert[on_v], kind="stable")]
    v_sorted = vert[on_v]
    head = np.concatenate(([True], v_sorted[1:] != v_sorted[:-1]))
    size = np.diff(np.append(np.flatnonzero(head), len(on_v)))
    group_size = np.repeat(size, size)
    two = on_v[group_size == 2].reshape(-1, 2)
    link[two[:, 0]], link[two[:, 1]] = two[:, 1], two[:, 0]
    cand = [_pairs_within_groups(on_v, np.repeat(np.arange(len(size)), size), int(size.max(initial=0)))]
    # ends left free: join across gaps of at most gap_px
    free = np.flatnonzero(link < 0)
    if gap_px > 0 and len(free) > 1:
        cand.append(free[pairs_within(end_uv[free], gap_px)])
    pairs = np.concatenate(cand)
    pairs = pairs[pairs[:, 0] // 2 != pairs[:, 1] // 2]
    if len(pairs):
        dist = np.linalg.norm(end_uv[pairs[:, 0]] - end_uv[pairs[:, 1]], axis=1)
        # a smooth continuation: the two ends point in opposite directions
        straight = -np.einsum("ij,ij->i", out_dir[pairs[:, 0]], out_dir[pairs[:, 1]])
        shared = vert[pairs[:, 0]] >= 0
        shared &= vert[pairs[:, 0]] == vert[pairs[:, 1]]
        ok = shared | (straight >= math.cos(math.radians(max_turn_deg)))
        pairs, dist, straight = pairs[ok], np.where(shared[ok], 0.0, dist[ok]), straight[ok]
        order = np.lexsort((pairs[:, 1], pairs[:, 0], -straight, dist))
        pairs = pairs[order]
    link_l = link.tolist()
    for a, b in pairs.tolist():  # greedy matching, best pair first
        if link_l[a] < 0 and link_l[b] < 0:
            link_l[a], link_l[b] = b, a

    # walk: open chains from a free end first, then the closed loops that remain
    used = [False] * n
    chains: list[list[int]] = []  # per chain, the ends by which it enters its runs, in order
    for loops in (False, True):
        for r in range(n):
            if used[r]:
                continue
            if loops:
                entry = 2 * r
            elif link_l[2 * r] < 0 or link_l[2 * r + 1] < 0:
                entry = 2 * r if link_l[2 * r] < 0 else 2 * r + 1
            else:
                continue
            seq = []
            while True:
                used[entry // 2] = True
                seq.append(entry)
                nxt = link_l[entry ^ 1]
                if nxt < 0 or used[nxt // 2]:
                    break
                entry = nxt
            chains.append(seq)
    return _assemble(chains, run_start, run_end, uv, nature[edge_of_run])


# with a point's own cell, these four neighbours see every pair of adjacent cells once
_HALF_NEIGHBOURS = ((0, 1), (1, -1), (1, 0), (1, 1))


def pairs_within(points: np.ndarray, radius: float) -> np.ndarray:
    """(k, 2) index pairs i < j of 2-D points at most ``radius`` apart (the pairs of scipy's
    ``cKDTree.query_pairs``), from a grid of cells ``radius`` wide: the worker is spared
    importing scipy (~0.3 CPU s per batch) for a few hundred stroke ends a view."""
    pts = np.asarray(points, np.float64)
    n = len(pts)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    # cells a hair wider than the radius: two points within it are never two cells apart
    cell = np.floor(pts / (radius * (1.0 + 1e-9))).astype(np.int64)
    cell -= cell.min(axis=0)
    width = int(cell[:, 1].max()) + 3
    key = (cell[:, 0] + 1) * width + cell[:, 1] + 1
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    found = []
    for dx, dy in ((0, 0), *_HALF_NEIGHBOURS):
        target = key + dx * width + dy
        lo = np.searchsorted(sorted_key, target, "left")
        count = np.searchsorted(sorted_key, target, "right") - lo
        i = np.repeat(np.arange(n), count)
        j = order[np.repeat(lo - np.cumsum(count) + count, count) + np.arange(count.sum())]
        if (dx, dy) == (0, 0):
            i, j = i[i < j], j[i < j]
        d = pts[i] - pts[j]
        near = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] <= radius * radius
        found.append(np.stack([np.minimum(i, j)[near], np.maximum(i, j)[near]], axis=1))
    return np.concatenate(found)


def _pairs_within_groups(members: np.ndarray, group: np.ndarray, largest: int) -> np.ndarray:
    """Every pair of members of the same group (``group`` sorted, groups of up to ``largest``)."""
    out = [np.zeros((0, 2), np.int64)]
    for d in range(1, largest):
        same = np.flatnonzero(group[d:] == group[:-d])
        out.append(np.stack([members[same], members[same + d]], axis=1))
    return np.concatenate(out)


def _assemble(
    chains: list[list[int]], run_start: np.ndarray, run_end: np.ndarray, uv: np.ndarray, run_nature: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Concatenate each chain's runs (entered at their start: forward, else backward), the point
    where two runs share a mesh vertex kept once."""
    entries = np.fromiter((e for seq in chains for e in seq), np.int64)
    n_per_chain = np.array([len(seq) for seq in chains])
    r, fwd = entries // 2, entries % 2 == 0
    first_i = np.where(fwd, run_start[r], run_end[r])
    last_i = np.where(fwd, run_end[r], run_start[r])
    chain_first = np.zeros(len(entries), bool)
    first_entry = np.cumsum(n_per_chain) - n_per_chain
    chain_first[first_entry] = True
    drop = np.zeros(len(entries), np.int64)
    same = (uv[first_i[1:]] == uv[last_i[:-1]]).all(axis=1)
    drop[1:] = same & ~chain_first[1:]
    count = run_end[r] - run_start[r] + 1 - drop
    rep = np.repeat(np.arange(len(entries)), count)
    offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count) + drop[rep]
    idx = np.where(fwd[rep], first_i[rep] + offset, first_i[rep] - offset)
    points, kinds = uv[idx], run_nature[r][rep]
    cuts = np.cumsum(np.add.reduceat(count, first_entry))[:-1]
    return list(zip(np.split(points, cuts), np.split(kinds, cuts)))


def _length(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def draw_strokes(strokes: list[np.ndarray], size: int, thickness: float) -> np.ndarray:
    """Polylines (pixel coordinates, pixel i covering [i, i+1)) drawn black on white as uint8 gray
    the way a one-sample Freestyle render draws them: a pixel is ink when its centre lies within
    ``thickness / 2`` of a line (no anti-aliasing)."""
    canvas = np.full((size, size), 255, np.uint8)
    segs = [np.stack([p[:-1], p[1:]], axis=1) for p in map(np.asarray, strokes) if len(p) >= 2]
    if not segs:
        return canvas
    seg = np.concatenate(segs).astype(np.float64)
    # cut segments into pieces at most 1 px long, so a 4x4 pixel block holds each piece's ink
    n = np.maximum(1, np.ceil(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1))).astype(np.int64)
    k = np.repeat(np.arange(len(seg)), n)
    f = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n))[:, None]
    a = seg[k, 0] + (seg[k, 1] - seg[k, 0]) * (f / n[k, None])
    b = seg[k, 0] + (seg[k, 1] - seg[k, 0]) * ((f + 1) / n[k, None])
    r = 0.5 * thickness
    # pixel centres (i + 0.5) within r of a piece lie in its box grown by r: at most
    # floor(1 + 2r) + 1 of them per axis, starting at the first centre >= the box's low side
    base = np.ceil(np.minimum(a, b) - r - 0.5).astype(np.int64)
    reach = int(np.floor(1.0 + 2.0 * r)) + 1
    ox, oy = np.meshgrid(np.arange(reach), np.arange(reach), indexing="xy")
    pu = base[:, :1] + ox.ravel()[None]  # (m, reach²) pixel columns
    pv = base[:, 1:] + oy.ravel()[None]  # and rows
    du, dv = (b - a)[:, :1], (b - a)[:, 1:]
    cu, cv = pu + 0.5 - a[:, :1], pv + 0.5 - a[:, 1:]
    t = np.clip((cu * du + cv * dv) / np.maximum(du * du + dv * dv, 1e-12), 0.0, 1.0)
    ex, ey = cu - t * du, cv - t * dv
    hit = (ex * ex + ey * ey <= r * r) & (pu >= 0) & (pu < size) & (pv >= 0) & (pv < size)
    canvas[pv[hit], pu[hit]] = 0
    return canvas
