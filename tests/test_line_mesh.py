"""The line mesh (what the renderer draws) keeps the source's sharp edges and is cleaned of what
makes Freestyle draw lines the object does not have; the line-fidelity score sees both."""

from __future__ import annotations

import numpy as np
import trimesh
from PIL import Image, ImageDraw

from pipeline.prepare.line_mesh import border_edges, line_mesh, sharp_edges
from render.cameras import make_view
from render.line_fidelity import score_view
from render.settings import RenderSettings


def _soup_box() -> tuple[np.ndarray, np.ndarray]:
    """A 2×1×1 box as a CAD export might give it: every face with its own vertices (split
    seams), two faces flipped, one face duplicated reversed, one zero-area face."""
    box = trimesh.creation.box((2.0, 1.0, 1.0))
    tri = box.vertices[box.faces]
    faces = np.arange(len(tri) * 3).reshape(-1, 3)
    faces[[1, 6]] = faces[[1, 6]][:, ::-1]
    v = tri.reshape(-1, 3)
    extra_v = np.vstack([v[faces[3]][::-1], [v[0], v[0], v[1]]])
    n = len(v)
    faces = np.vstack([faces, [[n, n + 1, n + 2], [n + 3, n + 4, n + 5]]])
    return np.vstack([v, extra_v]) + [5.0, 0.0, 0.0], faces


def test_soup_becomes_closed_outward_box_with_its_twelve_creases():
    v, f = _soup_box()
    m = line_mesh(v, f, center=np.array([5.0, 0.0, 0.0]), scale=2.0, max_faces=20000)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    assert len(border_edges(m)) == 0  # split seams merged: no border lines across the faces
    assert np.allclose(m.bounds, [[-0.5, -0.25, -0.25], [0.5, 0.25, 0.25]])
    sharp = sharp_edges(m, 45.0)
    # the box's 12 edges and nothing else (diagonals of the split faces are flat)
    length = np.linalg.norm(m.vertices[sharp[:, 0]] - m.vertices[sharp[:, 1]], axis=1).sum()
    assert np.isclose(length, 4 * (1.0 + 0.5 + 0.5))


def test_long_slivers_split_without_new_creases_and_big_meshes_decimated_keeping_edges():
    cyl = trimesh.creation.cylinder(radius=0.3, height=1.6, sections=48)  # long side slivers
    m = line_mesh(cyl.vertices, cyl.faces, np.zeros(3), 1.0, max_faces=20000)
    assert m.edges_unique_length.max() <= 0.2 + 1e-9 and len(m.faces) <= 20000
    assert m.is_watertight and len(border_edges(m)) == 0
    rims = sharp_edges(m, 45.0)
    assert np.isclose(
        np.linalg.norm(m.vertices[rims[:, 0]] - m.vertices[rims[:, 1]], axis=1).sum(),
        2 * 48 * 2 * 0.3 * np.sin(np.pi / 48),
    )
    # A dense box: decimated to the budget, still a box with sharp corners.
    dense = trimesh.creation.box((1.0, 1.0, 1.0)).subdivide_to_size(0.05)
    small = line_mesh(dense.vertices, dense.faces, np.zeros(3), 1.0, max_faces=1000)
    assert len(small.faces) <= 1000 < len(dense.faces)
    assert np.allclose(small.bounds, dense.bounds, atol=1e-6)
    assert np.isclose(small.volume, 1.0, rtol=1e-3)


def _draw(size: int, lines: list[np.ndarray]) -> np.ndarray:
    im = Image.new("L", (size, size), 255)
    d = ImageDraw.Draw(im)
    for pts in lines:
        d.line([tuple(p) for p in pts], fill=0, width=1)
    return np.asarray(im)


def test_fidelity_score_rewards_the_edges_and_punishes_missing_or_stray_ink():
    s = RenderSettings(image_size=128)
    view = make_view(s, 30.0, 20.0)
    cam = view.to_json()
    box = line_mesh(*_soup_box(), center=np.array([5.0, 0.0, 0.0]), scale=2.0, max_faces=20000)
    h = np.c_[box.vertices, np.ones(len(box.vertices))] @ view.projection.T
    uv = h[:, :2] / h[:, 2:3]
    edges = sharp_edges(box, 45.0)
    all_edges = _draw(128, [uv[e] for e in edges])  # hidden ones too: the 3 back edges are stray
    visible = score_view(box, cam, all_edges, 45.0)
    assert visible.recall > 0.95
    assert 0.6 < visible.precision < 0.95  # the hidden back edges are ink on no visible line
    blank = score_view(box, cam, np.full((128, 128), 255, np.uint8), 45.0)
    assert blank.recall == 0.0 and blank.sharp_total > 100
    stray = score_view(box, cam, _draw(128, [np.array([[5, 5], [5, 120]])]), 45.0)
    assert stray.precision == 0.0
