"""Slow render tests: procedural models of every category, prepared, rendered at defaults."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from scipy import ndimage

from pipeline.core.atomic import read_json
from render.batch import render_batch
from render.cameras import project
from render.settings import RenderSettings

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    from pipeline.core.schema import LINE_MESH_FILE
    from pipeline.prepare.batch import PrepareSettings, prepare_batch
    from pipeline.shapes import CATEGORIES
    from pipeline.sources.layouts import list_models

    work = tmp_path_factory.mktemp("work")
    out = {}
    for cat in CATEGORIES:
        refs = list_models("procedural", cat, 1, 0, work)
        recs = prepare_batch(refs, work / "prepare", PrepareSettings())
        out[cat] = [
            (r.model_id, work / "prepare" / cat / r.model_id / LINE_MESH_FILE)
            for r, rec in zip(refs, recs)
            if rec["status"] == "ok"
        ]
    return work, out


def check_model(folder: Path, mesh_path: Path, n_views: int, size: int) -> None:
    mesh = trimesh.load(mesh_path, force="mesh", process=False)
    cams = read_json(folder / "cameras.json")
    strokes = read_json(folder / "strokes.json")["views"]
    assert len(cams["views"]) == len(strokes) == n_views
    for i, view in enumerate(cams["views"]):
        a = np.asarray(Image.open(folder / f"view_{i:02d}.png"))
        assert a.shape == (size, size) and a.dtype == np.uint8
        ys, xs = np.nonzero(a < 250)
        uv = project(np.array(view["projection"]), mesh.vertices)
        ink_box = np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1])
        # 3 px: on the coarse source tessellation (a mug's 45° bottom bevel is two faces) the
        # smooth silhouette runs inside the polygon's extreme vertices by up to ~2.5 px
        assert np.abs(ink_box - np.r_[uv.min(0), uv.max(0)]).max() <= 3.0
        assert {s["type"] for s in strokes[i]} & {"silhouette", "border"}
        pts = np.concatenate([np.asarray(s["points"]) for s in strokes[i]])
        dist = ndimage.distance_transform_edt(a >= 200)
        px = np.clip(np.floor(pts).astype(int), 0, size - 1)
        assert (dist[px[:, 1], px[:, 0]] <= 1.5).mean() >= 0.95


def test_every_category_at_defaults(prepared, tmp_path):
    work, items = prepared
    s = RenderSettings()
    for cat, cat_items in items.items():
        assert cat_items, f"prepare gave no {cat} model"
        recs = render_batch(cat, cat_items, tmp_path, s, seed=0)
        for (mid, mesh), rec in zip(cat_items, recs):
            assert rec["status"] == "ok", rec
            check_model(tmp_path / cat / mid, mesh, s.views, s.image_size)


def test_orthographic_front_side_top(prepared, tmp_path):
    work, items = prepared
    s = RenderSettings(rig="front_side_top", orthographic=True)
    cat_items = items["car"]
    recs = render_batch("car", cat_items, tmp_path, s, seed=0)
    assert recs[0]["status"] == "ok"
    check_model(tmp_path / "car" / cat_items[0][0], cat_items[0][1], 3, 256)


def test_fragment_joining_only_chains_captured_points(prepared, tmp_path):
    # the airplane's thin wings make Freestyle split outlines into many tiny fragments
    work, items = prepared
    cat_items = items["airplane"]
    raw_s = RenderSettings(views=2, join_gap_px=0.0)
    joined_s = RenderSettings(views=2)
    render_batch("airplane", cat_items, tmp_path / "raw", raw_s, seed=0)
    render_batch("airplane", cat_items, tmp_path / "joined", joined_s, seed=0)
    mid = cat_items[0][0]
    raw = read_json(tmp_path / "raw" / "airplane" / mid / "strokes.json")["views"]
    joined = read_json(tmp_path / "joined" / "airplane" / mid / "strokes.json")["views"]
    for i in range(2):
        # same drawing: joining is a capture-side step only
        a = np.asarray(Image.open(tmp_path / "raw" / "airplane" / mid / f"view_{i:02d}.png"))
        b = np.asarray(Image.open(tmp_path / "joined" / "airplane" / mid / f"view_{i:02d}.png"))
        assert np.array_equal(a, b)
        assert len(joined[i]) < 0.8 * len(raw[i]), (len(joined[i]), len(raw[i]))
        # every joined point is a captured point (nothing moved or invented)
        raw_pts = {tuple(p) for s in raw[i] for p in s["points"]}
        assert {tuple(p) for s in joined[i] for p in s["points"]} <= raw_pts


def test_line_mesh_drawings_are_faithful_and_byte_identical(prepared, tmp_path):
    """The car's line mesh drawn twice: same bytes; its source's sharp edges are inked and the
    ink lies on the source's lines (bench/bench_lines.py measures this per category)."""
    from pipeline.core.records import read_record
    from pipeline.prepare.line_mesh import line_mesh
    from pipeline.sources.mesh_io import load_mesh
    from render.line_fidelity import ViewScore, score_view

    work, items = prepared
    s = RenderSettings(views=3)
    for run in ("a", "b"):
        render_batch("car", items["car"], tmp_path / run, s, seed=0)
    mid = items["car"][0][0]
    for name in ("view_00.png", "view_01.png", "view_02.png", "strokes.json", "cameras.json"):
        assert (tmp_path / "a" / "car" / mid / name).read_bytes() == (tmp_path / "b" / "car" / mid / name).read_bytes()
    rec = read_record(work / "prepare" / "car" / mid)
    norm = rec["normalization"]
    source = line_mesh(*load_mesh(rec["source"]["path"]), np.array(norm["center"]), norm["scale"], 1 << 62)
    cams = read_json(tmp_path / "a" / "car" / mid / "cameras.json")["views"]
    total = ViewScore(0, 0, 0, 0)
    for i, cam in enumerate(cams):
        gray = np.asarray(Image.open(tmp_path / "a" / "car" / mid / f"view_{i:02d}.png"))
        total = total + score_view(source, cam, gray, 180.0 - s.crease_angle_deg)
    assert total.sharp_total > 500
    assert total.recall >= 0.9 and total.precision >= 0.95, (total.recall, total.precision)
