"""CPU thumbnails and contact sheets."""

from __future__ import annotations

import time

import numpy as np
import pytest
import trimesh
from PIL import Image

from pipeline.core.images import contact_sheet, encode_png, save_png
from pipeline.core.thumbnails import render_mesh


@pytest.fixture(scope="module")
def box():
    m = trimesh.creation.box(extents=(1.0, 2.0, 0.5))
    return m.vertices, m.faces


def test_render_draws_object_on_white(box):
    img = render_mesh(*box, size=64)
    assert img.shape == (64, 64, 3) and img.dtype == np.uint8
    ink = (img < 250).any(axis=2)
    assert 0.1 < ink.mean() < 0.9
    corners = img[[0, 0, -1, -1], [0, -1, 0, -1]]
    assert (corners == 255).all()
    # Auto-fit: object touches neither edge but spans most of the frame.
    rows, cols = np.nonzero(ink)
    assert rows.min() > 0 and rows.max() < 63 and rows.max() - rows.min() > 45


def test_render_deterministic(box):
    a = render_mesh(*box, size=96, azimuth_deg=40, elevation_deg=10)
    b = render_mesh(*box, size=96, azimuth_deg=40, elevation_deg=10)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, render_mesh(*box, size=96, azimuth_deg=80, elevation_deg=10))


def test_face_colors_honoured(box):
    v, f = box
    red = render_mesh(v, f, size=64, face_colors=np.tile([255, 0, 0], (len(f), 1)), outline=False)
    ink = (red < 250).any(axis=2)
    px = red[ink].astype(int)
    assert (px[:, 0] > px[:, 1] + 40).mean() > 0.95 and (px[:, 1] == px[:, 2]).all()
    # Float colours in [0, 1] and one colour for all faces are accepted too.
    green = render_mesh(v, f, size=64, face_colors=np.array([0.0, 1.0, 0.0]), outline=False)
    assert (green[ink][:, 1] > green[ink][:, 0]).all()


def test_z_buffer_keeps_nearest_surface():
    near = trimesh.creation.box(extents=(1, 1, 0.1))
    far = trimesh.creation.box(extents=(3, 3, 0.1))
    far.apply_translation((0, 0, 1.0))  # behind: the default-ish front view looks along +z
    v = np.concatenate([near.vertices, far.vertices])
    f = np.concatenate([near.faces, far.faces + len(near.vertices)])
    colors = np.concatenate([np.tile([255, 0, 0], (12, 1)), np.tile([0, 0, 255], (12, 1))])
    img = render_mesh(v, f, size=60, azimuth_deg=0, elevation_deg=0, face_colors=colors, outline=False)
    c = img[30, 30].astype(int)
    assert c[0] > 100 and c[2] == 0  # the near red box hides the blue one at the centre
    assert img[8, 8, 2] > 100 and img[8, 8, 0] == 0  # the far box shows around it


def test_flipped_faces_still_shaded(box):
    v, f = box
    a = render_mesh(v, f, size=48)
    b = render_mesh(v, f[:, ::-1], size=48)
    assert np.array_equal(a, b)


def test_empty_mesh_is_blank():
    img = render_mesh(np.zeros((0, 3)), np.zeros((0, 3), int), size=32)
    assert (img == 255).all()


def test_fast_on_50k_faces():
    m = trimesh.creation.icosphere(subdivisions=6)  # 81,920 faces
    render_mesh(m.vertices, m.faces, size=256)
    t = time.perf_counter()
    img = render_mesh(m.vertices, m.faces, size=256)
    assert time.perf_counter() - t < 2.0  # ~0.3 s typical; generous for a loaded 2-core machine
    assert (img < 250).any()


def test_contact_sheet_grid_and_labels():
    gray = np.full((20, 30), 0, np.uint8)
    rgb = np.zeros((10, 10, 3), np.uint8)
    rgb[..., 1] = 200
    plain = contact_sheet([gray, rgb, gray], cols=2)
    labelled = contact_sheet([gray, rgb, gray], ["a", "b", "c"], cols=2)
    assert plain.dtype == np.uint8 and plain.ndim == 3 and plain.shape[2] == 3
    assert labelled.shape[0] > plain.shape[0] and labelled.shape[1] == plain.shape[1]
    assert plain.shape[1] >= 2 * 30 and plain.shape[0] >= 2 * 20
    assert (plain[..., 1] == 200).any() and (plain == 0).all(axis=2).any()
    # Labels add dark text pixels below the cells.
    strip = labelled[4 + 20 : 4 + 20 + 14]
    assert (strip < 128).any()
    with pytest.raises(ValueError):
        contact_sheet([gray], ["a", "b"])


def test_save_png_deterministic_and_lossless(tmp_path):
    img = np.random.default_rng(0).integers(0, 256, (17, 23, 3), dtype=np.uint8)
    save_png(tmp_path / "a.png", img)
    save_png(tmp_path / "b.png", img)
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    assert np.array_equal(np.asarray(Image.open(tmp_path / "a.png")), img)
    gray = img[..., 0]
    assert Image.open(__import__("io").BytesIO(encode_png(gray))).mode == "L"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
