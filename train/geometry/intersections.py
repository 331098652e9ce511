"""Self-intersections of a welded triangle mesh and the patch pairs they come from.

A face pair counts as intersecting when the two triangles share no vertex and an edge of one
crosses the other (``triangles_intersect``). Faces that share a vertex touch by
construction and are skipped, so on a conforming mesh (``quad_mesh``: neighbouring patches
share their boundary vertices, T-junctions included) only real crossings are counted: folds
inside a patch and patches passing through each other. Candidate pairs come from a k-d tree of
face centroids, so the cost grows with the number of nearby pairs, not with F².

Use ``mesh_intersections`` on a mesh you already have (``predict``'s ``mesh.obj``) and
``train.export.quadmesh.patch_intersections`` on raw patch control points ``(P, 4, 4, 3)``.

``count_intersecting_pairs`` is the figure ``evaluate`` reports: on the loss's own truncated grid
triangulation (pairs sharing a boundary leave out a band along it), independent of the collision
loss, with patches of absent parts left out.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree
from torch import Tensor

from train.geometry.patch_pairs import CollisionPairs, unconnected_pairs
from train.geometry.triangulate import triangulate_patches

# face pairs tested per exact-test batch (keeps the (N, 3, 3) temporaries small)
_BATCH = 200_000


@dataclasses.dataclass(frozen=True)
class Intersections:
    face_pairs: np.ndarray  # (K, 2) crossing faces, i < j, sorted
    patch_pairs: list[tuple[int, int]]  # distinct patches whose faces cross, (a < b), sorted
    folded_patches: list[int]  # patches with a face crossing another face of the same patch

    @property
    def faces(self) -> np.ndarray:
        """Indices of the self-intersecting faces (each face once)."""
        return np.unique(self.face_pairs)

    @property
    def clean(self) -> bool:
        return len(self.face_pairs) == 0

    def summary(self) -> dict:
        return {
            "self_intersecting_faces": int(len(self.faces)),
            "intersecting_patch_pairs": len(self.patch_pairs),
            "folded_patches": len(self.folded_patches),
        }


def candidate_pairs(triangles: np.ndarray) -> np.ndarray:
    """Face pairs ``(K, 2)``, i < j, whose bounding boxes overlap.

    Two triangles can only meet if their centroids are within the sum of their radii (largest
    centroid-to-corner distance). Typical faces are paired by one k-d tree query at twice the
    largest typical radius; the few large faces (a stretched patch) are queried one by one at
    their own radius plus the largest, so one long sliver does not make every pair a candidate.
    The boxes then prune the list.
    """
    n = len(triangles)
    if n < 2:
        return np.zeros((0, 2), int)
    centre = triangles.mean(axis=1)
    radius = np.linalg.norm(triangles - centre[:, None], axis=-1).max(axis=1) * (1 + 1e-9)
    typical = radius <= 4.0 * np.median(radius)
    small = np.nonzero(typical)[0]
    found = [small[cKDTree(centre[small]).query_pairs(2.0 * radius[small].max(), output_type="ndarray")]]
    large = np.nonzero(~typical)[0]
    if len(large):
        near = cKDTree(centre).query_ball_point(centre[large], radius[large] + radius.max())
        found.append(np.array([(i, j) for i, js in zip(large, near) for j in js if j != i], int).reshape(-1, 2))
    pairs = np.sort(np.concatenate(found), axis=1)
    key = np.unique(pairs[:, 0] * n + pairs[:, 1])  # query_pairs and the large faces' queries overlap
    pairs = np.stack([key // n, key % n], axis=1)
    lo, hi = triangles.min(axis=1), triangles.max(axis=1)
    overlap = np.all((lo[pairs[:, 0]] <= hi[pairs[:, 1]]) & (lo[pairs[:, 1]] <= hi[pairs[:, 0]]), axis=1)
    return pairs[overlap]


def mesh_intersections(
    vertices: np.ndarray, faces: np.ndarray, patch_of_face: np.ndarray | None = None
) -> Intersections:
    """Crossing face pairs of a triangle mesh ``vertices (V, 3)``, ``faces (F, 3)``; with
    ``patch_of_face (F,)`` they are also grouped into patch pairs and folded patches."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    tri = v[f]
    cand = candidate_pairs(tri)
    # faces sharing a vertex touch there by construction: not an intersection
    shared = (f[cand[:, 0]][:, :, None] == f[cand[:, 1]][:, None, :]).any(axis=(1, 2))
    cand = cand[~shared]
    hits = [
        cand[s : s + _BATCH][triangles_intersect(tri[cand[s : s + _BATCH, 0]], tri[cand[s : s + _BATCH, 1]])]
        for s in range(0, len(cand), _BATCH)
    ]
    pairs = np.concatenate(hits) if hits else np.zeros((0, 2), int)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))] if len(pairs) else pairs.reshape(0, 2)
    if patch_of_face is None:
        return Intersections(pairs, [], [])
    owner = np.asarray(patch_of_face)[pairs]
    across = owner[:, 0] != owner[:, 1]
    patch_pairs = sorted({(int(min(a, b)), int(max(a, b))) for a, b in owner[across]})
    folded = sorted({int(a) for a in owner[~across, 0]})
    return Intersections(pairs, patch_pairs, folded)


def _segments_hit_triangles(p0: np.ndarray, p1: np.ndarray, tri: np.ndarray, tol: float) -> np.ndarray:
    """Möller–Trumbore: does segment p0→p1 cross triangle ``tri (..., 3, 3)``? → bool (...).
    ``tol`` > 0 widens the triangle and the segment by that much in their own parameters."""
    d = p1 - p0
    e1, e2 = tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]
    h = np.cross(d, e2)
    a = (e1 * h).sum(-1)
    ok = np.abs(a) > 1e-12
    f = np.where(ok, 1.0 / np.where(ok, a, 1.0), 0.0)
    s = p0 - tri[..., 0, :]
    u = f * (s * h).sum(-1)
    q = np.cross(s, e1)
    v = f * (d * q).sum(-1)
    t = f * (e2 * q).sum(-1)
    return ok & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol) & (t >= -tol) & (t <= 1 + tol)


def triangles_intersect(ta: np.ndarray, tb: np.ndarray, tol: float = 0.0) -> np.ndarray:
    """Pairwise test of triangles ``ta (N, 3, 3)`` with ``tb (N, 3, 3)`` (either may be one
    triangle, broadcast) → bool ``(N,)``.

    Two non-coplanar triangles intersect iff an edge of one crosses the other; coplanar overlaps
    (measure zero for fitted patches) are not reported. ``tol`` > 0 counts near-touching pairs
    too (the template checks, where patches must keep clear of each other).
    """
    ta, tb = np.broadcast_arrays(ta, tb)
    hit = np.zeros(len(ta), dtype=bool)
    for x, y in ((ta, tb), (tb, ta)):
        for e in range(3):
            hit |= _segments_hit_triangles(x[:, e], x[:, (e + 1) % 3], y, tol)
    return hit


def count_intersecting_pairs(
    patches: Tensor, pairs: CollisionPairs | None = None, present: Tensor | None = None
) -> int:
    """Number of patch pairs whose (truncated) triangulations intersect, for one shape
    ``patches (P, 4, 4, 3)``. ``pairs`` from ``collision_pairs(template)`` truncates pairs that
    share a boundary; by default every pair is tested in full. ``present (P,)`` bool leaves out
    patches of absent parts. Boxes cull patch pairs and triangle pairs before the exact test."""
    pairs = pairs or unconnected_pairs(patches.shape[-4])
    on = None if present is None else present.cpu().numpy()
    verts, faces = triangulate_patches(patches.detach().double().cpu(), pairs.grid)
    tris = verts.numpy()[:, faces.numpy()]  # (P, F, 3, 3)
    f_np = faces.numpy()
    lo, hi = tris.min(axis=2), tris.max(axis=2)  # (P, F, 3)
    plo, phi = lo.min(axis=1), hi.max(axis=1)
    count = 0
    for k, (i, j) in enumerate(pairs.pairs.tolist()):
        if (on is not None and not (on[i] and on[j])) or np.any(plo[i] > phi[j]) or np.any(plo[j] > phi[i]):
            continue
        ki = pairs.keep_i[k].numpy()[f_np].all(-1)
        kj = pairs.keep_j[k].numpy()[f_np].all(-1)
        fi, fj = np.nonzero(ki)[0], np.nonzero(kj)[0]
        overlap = np.all(lo[i][fi][:, None] <= hi[j][fj][None], -1) & np.all(lo[j][fj][None] <= hi[i][fi][:, None], -1)
        a, b = np.nonzero(overlap)
        if len(a) and triangles_intersect(tris[i][fi[a]], tris[j][fj[b]]).any():
            count += 1
    return count
