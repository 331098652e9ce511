"""How faithfully a drawing shows a mesh's lines: sharp-edge recall and ink precision.

Reference lines come from the *source* mesh (in the prepared frame) seen from the drawing's
camera: its sharp edges (normals turning by more than ``turn_deg``), its occluding contours
(edges between a front- and a back-facing face) and its borders. Each edge is sampled every
half pixel along its projection and kept where a z-buffer of the same mesh says it is visible.

- recall: of the visible sharp-edge samples, the share within ``tol_px`` of ink;
- precision: of the ink pixels, the share within ``tol_px`` of a visible reference sample;
- outline recall (a check, not a goal): of the visible contour and border samples, the share
  within ``tol_px`` of ink.

Pure numpy (+ scipy's distance transform); no Blender.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import trimesh
from scipy import ndimage

from pipeline.core.thumbnails import rasterize
from pipeline.prepare.line_mesh import border_edges, sharp_edges

INK_LEVEL = 160  # gray below this is ink (lines are black, anti-aliased, on white)
STEP_PX = 0.5  # sampling step along projected edges
DEPTH_TOL = 0.01  # world units (model radius 1): a sample this far behind the z-buffer still shows


@dataclasses.dataclass
class ViewScore:
    sharp_total: int  # visible sharp-edge samples
    sharp_hit: int  # ... within tol of ink
    ink_total: int  # ink pixels
    ink_hit: int  # ... within tol of a visible reference line
    outline_total: int = 0  # visible contour and border samples
    outline_hit: int = 0  # ... within tol of ink
    faces: int = 0  # bookkeeping for reports (not part of the score)
    cpu_per_view: float = 0.0

    def __add__(self, other: "ViewScore") -> "ViewScore":
        return ViewScore(*(a + b for a, b in zip(dataclasses.astuple(self)[:6], dataclasses.astuple(other)[:6])))

    @property
    def recall(self) -> float:
        return self.sharp_hit / self.sharp_total if self.sharp_total else 1.0

    @property
    def outline_recall(self) -> float:
        """Share of visible contours and borders inked (not a goal of the issue: a check that
        smooth silhouettes are not lost)."""
        return self.outline_hit / self.outline_total if self.outline_total else 1.0

    @property
    def precision(self) -> float:
        return self.ink_hit / self.ink_total if self.ink_total else 1.0


def _camera_points(world_to_camera: np.ndarray, projection: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n, 3): pixel u, pixel v, camera depth."""
    h = np.c_[points, np.ones(len(points))]
    uvw = h @ projection.T
    depth = (h @ world_to_camera.T)[:, 2]
    return np.c_[uvw[:, :2] / uvw[:, 2:3], depth]


def contour_edges(mesh: trimesh.Trimesh, eye: np.ndarray | None, direction: np.ndarray | None) -> np.ndarray:
    """(k, 2) vertex pairs of edges between a front-facing and a back-facing face.

    Perspective views give ``eye`` (faces see it or not); orthographic views give the viewing
    ``direction``.
    """
    normals = mesh.face_normals
    if eye is not None:
        facing = np.einsum("ij,ij->i", normals, eye - mesh.triangles_center) > 0
    else:
        facing = normals @ -direction > 0
    pairs = mesh.face_adjacency
    return mesh.face_adjacency_edges[facing[pairs[:, 0]] != facing[pairs[:, 1]]]


def _edge_samples(screen: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(n, 3) points every STEP_PX along each projected edge (u, v, depth linear in between).

    Depth is interpolated linearly in screen space: exact for orthographic views and within a
    fraction of DEPTH_TOL for the short edges of a mesh seen in perspective.
    """
    if len(edges) == 0:
        return np.zeros((0, 3))
    a, b = screen[edges[:, 0]], screen[edges[:, 1]]
    length = np.linalg.norm(b[:, :2] - a[:, :2], axis=1)
    n = np.minimum(np.ceil(length / STEP_PX).astype(np.int64) + 1, 4096)
    idx = np.repeat(np.arange(len(edges)), n)
    t = (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(np.maximum(n - 1, 1), n)
    return a[idx] + (b[idx] - a[idx]) * t[:, None]


def _visible(samples: np.ndarray, zbuf: np.ndarray) -> np.ndarray:
    """Samples inside the image and not behind the surface (3×3 farthest depth: lines on a
    silhouette border the background and count as visible)."""
    S = zbuf.shape[0]
    u, v = np.floor(samples[:, 0]).astype(np.int64), np.floor(samples[:, 1]).astype(np.int64)
    inside = (u >= 0) & (u < S) & (v >= 0) & (v < S)
    far = ndimage.maximum_filter(np.where(np.isinf(zbuf), 1e9, zbuf), size=3, mode="nearest")
    ok = np.zeros(len(samples), bool)
    ok[inside] = samples[inside, 2] <= far[v[inside], u[inside]] + DEPTH_TOL
    return ok


def score_view(
    mesh: trimesh.Trimesh, camera: dict, gray: np.ndarray, turn_deg: float, tol_px: float = 2.0
) -> ViewScore:
    """Recall and precision counts of one drawing (``gray`` uint8) of ``mesh`` from ``camera``
    (a cameras.json view: world_to_camera, projection, orthographic)."""
    S = gray.shape[0]
    w2c = np.asarray(camera["world_to_camera"], float)
    P = np.asarray(camera["projection"], float)
    screen = _camera_points(w2c, P, mesh.vertices)
    _, zbuf = rasterize(screen, mesh.faces, S, S)
    R, t = w2c[:3, :3], w2c[:3, 3]
    if camera.get("orthographic"):
        eye, direction = None, R.T @ np.array([0.0, 0.0, 1.0])
    else:
        eye, direction = -R.T @ t, None

    sharp = _edge_samples(screen, sharp_edges(mesh, turn_deg))
    sharp = sharp[_visible(sharp, zbuf)]
    others = _edge_samples(screen, np.vstack([contour_edges(mesh, eye, direction), border_edges(mesh)]))
    others = others[_visible(others, zbuf)]

    ink = gray < INK_LEVEL
    # distance of every pixel to the nearest ink pixel, and to the nearest reference line pixel
    to_ink = ndimage.distance_transform_edt(~ink) if ink.any() else np.full(ink.shape, np.inf)
    su, sv = np.floor(sharp[:, 0]).astype(np.int64), np.floor(sharp[:, 1]).astype(np.int64)
    sharp_hit = int((to_ink[sv, su] <= tol_px).sum())

    ref = np.zeros_like(ink)
    for pts in (sharp, others):
        ref[np.floor(pts[:, 1]).astype(np.int64), np.floor(pts[:, 0]).astype(np.int64)] = True
    to_ref = ndimage.distance_transform_edt(~ref) if ref.any() else np.full(ink.shape, np.inf)
    ink_hit = int((to_ref[ink] <= tol_px).sum())
    ou, ov = np.floor(others[:, 0]).astype(np.int64), np.floor(others[:, 1]).astype(np.int64)
    outline_hit = int((to_ink[ov, ou] <= tol_px).sum())
    return ViewScore(len(sharp), sharp_hit, int(ink.sum()), ink_hit, len(others), outline_hit)
