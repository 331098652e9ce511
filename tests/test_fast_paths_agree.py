"""The pipeline's fast paths give exactly what the computations they replace give."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from augment.metrics import stroke_scores, stroke_scores_at
from augment.strokes import cut
from pipeline.prepare.line_mesh import _turn_bodies_outward
from render.cameras import _cross, make_view, project
from render.edge_lines import pairs_within
from render.rigs import seeded_views, silhouette_extents
from render.settings import RenderSettings


def _brute_pairs(points: np.ndarray, radius: float) -> set[tuple[int, int]]:
    d = points[:, None] - points[None]
    near = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] <= radius * radius
    i, j = np.nonzero(np.triu(near, 1))
    return set(zip(i.tolist(), j.tolist()))


@pytest.mark.parametrize("lattice", [False, True])
def test_pairs_within_finds_every_close_pair_once(lattice: bool) -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        pts = rng.uniform(-5.0, 260.0, (int(rng.integers(0, 300)), 2))
        if lattice:  # integer points: many pairs exactly at the radius
            pts = np.round(pts / 4.0)
        radius = float(rng.choice([1.0, 2.0, 3.0]))
        got = pairs_within(pts, radius)
        assert got.shape[1] == 2 and (got[:, 0] < got[:, 1]).all()
        assert len(set(map(tuple, got.tolist()))) == len(got)
        assert set(map(tuple, got.tolist())) == _brute_pairs(pts, radius)


def test_silhouette_extents_equal_projecting_view_by_view() -> None:
    s = RenderSettings()
    rng = np.random.default_rng(0)
    vertices = rng.normal(size=(500, 3)) * [1.0, 0.2, 0.05]
    pairs = seeded_views(s, 0, "knife", "k", 32)
    want = []
    for az, el in pairs:
        uv = np.clip(project(make_view(s, az, el).projection, vertices), 0.0, s.image_size)
        want.append(float((uv.max(axis=0) - uv.min(axis=0)).max() / s.image_size))
    assert silhouette_extents(s, vertices, pairs) == want


def test_cross_is_numpys() -> None:
    rng = np.random.default_rng(1)
    for a, b in rng.normal(size=(2000, 2, 3)):
        assert np.array_equal(_cross(a, b), np.cross(a, b))


def test_bodies_turned_outward_as_trimesh_does() -> None:
    parts = [trimesh.creation.box(), trimesh.creation.icosphere(1), trimesh.creation.cylinder(0.3, 1.0)]
    parts = [p.apply_translation([3.0 * i, 0.0, 0.0]) for i, p in enumerate(parts)]
    open_sheet = trimesh.Trimesh([[0, 0, 5], [1, 0, 5], [0, 1, 5], [1, 1, 5]], [[0, 1, 2], [1, 3, 2]])
    mesh = trimesh.util.concatenate(parts + [open_sheet])
    faces = mesh.faces.copy()
    faces[: len(parts[0].faces)] = faces[: len(parts[0].faces), ::-1]  # the box inside out
    faces[-2:] = faces[-2:, ::-1]  # the open sheet is left as it is either way
    ours = trimesh.Trimesh(mesh.vertices, faces.copy(), process=False)
    theirs = trimesh.Trimesh(mesh.vertices, faces.copy(), process=False)
    _turn_bodies_outward(ours)
    trimesh.repair.fix_inversion(theirs, multibody=True)
    assert np.array_equal(ours.faces, theirs.faces)
    assert not np.array_equal(ours.faces, faces)  # the box was flipped back


def test_scores_at_several_tolerances_are_the_single_ones() -> None:
    rng = np.random.default_rng(2)
    ref = [rng.uniform(10, 240, (int(rng.integers(2, 20)), 2)) for _ in range(12)]
    pred = [s + rng.normal(0, 1.2, s.shape) for s in ref[:10]]
    both = stroke_scores_at(pred, ref, 256, (2.0, 1.0))
    assert both == [stroke_scores(pred, ref, 256, tol=2.0), stroke_scores(pred, ref, 256, tol=1.0)]
    assert both[0]["recall"] > both[1]["recall"]


def test_compiled_cut_is_numpys_mask_and_interp() -> None:
    from augment.fitting import cumulative_length

    rng = np.random.default_rng(4)
    for n in (1, 2, 3, 5, 40):
        pts = np.cumsum(rng.normal(size=(n, 2)), axis=0)
        if n > 3:
            pts[2] = pts[1]  # a repeated point: equal arc lengths, np.interp's tie rule
        s = cumulative_length(pts)
        spans = [(0.0, 3.0), (2.5, 17.25), (-1.0, 1e9), (float(s[-1]) / 3, float(s[-1]) / 2)]
        for s0, s1 in spans + ([(s[1], s[-2]), (s[2], s[-1])] if n > 3 else []):
            a, b = max(0.0, s0), min(float(s[-1]), s1)
            want = np.concatenate(
                [
                    [[np.interp(a, s, pts[:, 0]), np.interp(a, s, pts[:, 1])]],
                    pts[(s > a) & (s < b)],
                    [[np.interp(b, s, pts[:, 0]), np.interp(b, s, pts[:, 1])]],
                ]
            )
            assert np.array_equal(cut(pts, s0, s1), want)


def test_small_holes_filled_as_skimage_fills_them() -> None:
    from skimage.morphology import remove_small_holes

    from augment.vectorize import fill_small_holes

    rng = np.random.default_rng(6)
    for p in (0.3, 0.5, 0.7, 0.9):
        for _ in range(10):
            mask = rng.random((48, 40)) < p
            for size in (0, 1, 6, 30):
                assert np.array_equal(fill_small_holes(mask, size), remove_small_holes(mask, max_size=size))
    ring = np.zeros((9, 9), bool)
    ring[2:7, 2:7] = True
    ring[4, 4] = False  # a one-pixel hole in a square of ink is filled; the paper around it is not
    assert fill_small_holes(ring, 6)[4, 4] and not fill_small_holes(ring, 6)[0, 0]
