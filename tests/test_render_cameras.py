"""Camera rig maths (pure numpy, no Blender)."""

from __future__ import annotations

import numpy as np
import pytest

from render.cameras import blender_matrix_world, project, rig
from render.rigs import seeded_views, silhouette_extent, silhouette_hull_areas
from render.settings import RenderSettings

SPHERE = np.random.default_rng(0).normal(size=(2000, 3))
SPHERE /= np.linalg.norm(SPHERE, axis=1, keepdims=True)


@pytest.mark.parametrize("name", ["random", "representative"])
def test_rig_is_seeded_per_model(name):
    s = RenderSettings(views=8, rig=name)
    a = rig(s, 0, "car", "00001", SPHERE)
    assert len(a) == 8
    again = rig(s, 0, "car", "00001", SPHERE)
    assert [v.azimuth_deg for v in a] == [v.azimuth_deg for v in again]
    assert [v.azimuth_deg for v in rig(s, 1, "car", "00001", SPHERE)] != [v.azimuth_deg for v in a]
    assert [v.azimuth_deg for v in rig(s, 0, "car", "00002", SPHERE)] != [v.azimuth_deg for v in a]
    el = np.array([v.elevation_deg for v in rig(RenderSettings(views=200, rig=name), 0, "car", "x", SPHERE)])
    assert el.min() >= -10 and el.max() <= 40 and el.max() - el.min() > 40


@pytest.mark.parametrize("ortho", [False, True])
def test_unit_sphere_fits_frame(ortho):
    s = RenderSettings(orthographic=ortho, views=20)
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(5000, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    for v in rig(s, 3, "mug", "a", pts):
        uv = project(v.projection, pts)
        assert uv.min() > 0 and uv.max() < s.image_size
        # the outline nearly fills the frame (margin 1.08)
        assert uv.max() - uv.min() > 0.85 * s.image_size


def test_projection_matches_camera_frame():
    s = RenderSettings(views=3)
    for v in rig(s, 0, "gun", "b", SPHERE):
        R = v.world_to_camera[:3, :3]
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
        # the origin projects to the image centre, world up projects upward (v decreases)
        c = project(v.projection, np.array([[0.0, 0.0, 0.0], [0.0, 0.3, 0.0]]))
        assert np.allclose(c[0], [128, 128])
        assert c[1, 1] < c[0, 1]
        assert np.isclose(np.linalg.norm(v.eye), v.distance)
        M = blender_matrix_world(v)
        # Blender camera looks along its local -Z: toward the origin
        assert np.allclose(-M[:3, 2], -v.eye / np.linalg.norm(v.eye))


def test_front_side_top_rig():
    s = RenderSettings(rig="front_side_top", orthographic=True)
    front, side, top = rig(s, 0, "car", "c", SPHERE)
    # front view: camera on -z; a point at +x appears on the image's left (model faces viewer)
    assert front.eye[2] < 0
    uv = project(front.projection, np.array([[0.5, 0.0, 0.0], [0.0, 0.0, 0.0]]))
    assert uv[0, 0] < uv[1, 0]
    assert side.eye[0] > 0
    assert top.eye[1] > 0
    # top view: the model's front (-z) is at the bottom of the image
    uv = project(top.projection, np.array([[0.0, 0.0, -0.5], [0.0, 0.0, 0.0]]))
    assert uv[0, 1] > uv[1, 1]
    # orthographic: depth does not change the projection
    a = project(front.projection, np.array([[0.2, 0.1, -0.5], [0.2, 0.1, 0.5]]))
    assert np.allclose(a[0], a[1])


def test_bad_settings_rejected():
    with pytest.raises(ValueError):
        RenderSettings(rig="spiral")
    with pytest.raises(ValueError):
        RenderSettings(elevation_range=(10.0, -10.0))


def _rod(length: float = 1.0, width: float = 0.05) -> np.ndarray:
    """A knife-like box: long along z, thin along x and y."""
    corners = np.array([[x, y, z] for x in (-width, width) for y in (-2 * width, 2 * width) for z in (-length, length)])
    return corners


def test_representative_rig_never_looks_down_a_rod():
    rod = _rod()
    random = RenderSettings(views=64, rig="random")
    ends_on = [
        silhouette_extent(random, rod, v.azimuth_deg, v.elevation_deg) for v in rig(random, 0, "knife", "k", rod)
    ]
    assert min(ends_on) < 0.35  # some random views look along the blade: a small blob
    s = RenderSettings(views=8)
    assert s.rig == "representative"
    for model in ("k", "l", "m"):
        views = rig(s, 0, "knife", model, rod)
        extents = [silhouette_extent(s, rod, v.azimuth_deg, v.elevation_deg) for v in views]
        assert len(views) == 8 and min(extents) >= 0.35


def _plate(span: float = 1.0, thickness: float = 0.02) -> np.ndarray:
    """A wing-like slab: wide along x and z, thin along y (up)."""
    return np.array([[x, y, z] for x in (-span, span) for y in (-thickness, thickness) for z in (-span / 2, span / 2)])


def test_view_area_fraction_keeps_views_that_show_the_plate_face_on():
    plate = _plate()
    by_extent = RenderSettings(views=4)
    by_area = RenderSettings(views=4, view_area_fraction=0.6)
    edge_on = []
    for model in ("a", "b", "c", "d", "e"):
        for s in (by_extent, by_area):
            pairs = [(v.azimuth_deg, v.elevation_deg) for v in rig(s, 0, "airplane", model, plate)]
            areas = silhouette_hull_areas(s, plate, pairs)
            best = max(silhouette_hull_areas(s, plate, seeded_views(s, 0, "airplane", model, s.view_candidates)))
            if s is by_area:
                assert len(pairs) == 4 and min(areas) >= 0.6 * best
                assert min(abs(e) for _, e in pairs) > 10  # never level with the wing
            else:
                edge_on.append(min(areas) / best)
    assert min(edge_on) < 0.6  # the extent alone lets a wing be drawn edge-on
    with pytest.raises(ValueError, match="view_area_fraction"):
        RenderSettings(view_area_fraction=1.5)
    # points that span no volume (a flat sheet) have no solid hull: their own projection is used
    sheet = np.array([[x, 0.0, z] for x in np.linspace(-1, 1, 10) for z in np.linspace(-0.5, 0.5, 10)])
    assert len(rig(by_area, 0, "airplane", "a", sheet)) == 4
    assert min(silhouette_hull_areas(by_area, sheet, [(30.0, 20.0), (30.0, 40.0)])) > 0


def test_representative_rig_keeps_random_views_of_a_round_model():
    """A sphere looks alike from everywhere: every candidate passes, so the views are the random
    rig's own draws (the first ``views`` of the candidates)."""
    s = RenderSettings(views=4)
    chosen = [(v.azimuth_deg, v.elevation_deg) for v in rig(s, 0, "mug", "a", SPHERE)]
    drawn = [
        (v.azimuth_deg, v.elevation_deg)
        for v in rig(RenderSettings(views=s.view_candidates, rig="random"), 0, "mug", "a", SPHERE)
    ]
    assert chosen == drawn[:4]


def test_too_few_wide_views_fill_with_the_widest():
    flat = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0]])  # a speck: no view reaches the floor
    s = RenderSettings(views=3, view_candidates=10)
    assert len(rig(s, 0, "x", "y", flat)) == 3
