"""Fast render tests: one Blender subprocess renders 3 small meshes + 1 broken file at 128², 2 views;
the output is shared by the tests through a module-scoped fixture."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from PIL import Image
from scipy import ndimage
from scipy.spatial import ConvexHull

from pipeline.core.atomic import read_json
from render import batch as batch_mod
from render.batch import RenderBatchError, render_batch
from render.cameras import project
from render.job import PROGRESS_PREFIX
from render.sample_meshes import write_samples
from render.settings import RenderSettings

SETTINGS = RenderSettings(views=2, image_size=128)
CATEGORY = "testshapes"
SEED = 7


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    root = tmp_path_factory.mktemp("render")
    items = write_samples(root / "meshes")
    broken = root / "meshes" / "broken.ply"
    broken.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nthis is not a mesh\n")
    items.insert(1, ("broken", broken))
    calls = []
    stage = root / "stage"
    records = render_batch(CATEGORY, items, stage, SETTINGS, SEED, progress=lambda d, t, m: calls.append((d, t, m)))
    meshes = {mid: trimesh.load(path, force="mesh", process=False) for mid, path in items if mid != "broken"}
    return {"root": root, "stage": stage, "items": items, "records": records, "calls": calls, "meshes": meshes}


def model_out(rendered, mid: str) -> Path:
    return rendered["stage"] / CATEGORY / mid


def ink(folder: Path, i: int) -> np.ndarray:
    return np.asarray(Image.open(folder / f"view_{i:02d}.png"))


def test_pngs_count_size_and_mode(rendered):
    for mid in rendered["meshes"]:
        folder = model_out(rendered, mid)
        pngs = sorted(folder.glob("view_*.png"))
        assert [p.name for p in pngs] == ["view_00.png", "view_01.png"]
        for p in pngs:
            im = Image.open(p)
            assert im.mode == "L" and im.size == (128, 128)
            a = np.asarray(im)
            assert (a < 128).sum() > 50, "no ink"
            assert a[0].min() == 255 and a[:, 0].min() == 255, "ink at the image border"


def test_records_and_broken_mesh_named(rendered):
    recs = {r["model_id"]: r for r in rendered["records"]}
    assert [r["model_id"] for r in rendered["records"]] == [mid for mid, _ in rendered["items"]]
    assert recs["broken"]["status"] == "failed"
    assert recs["broken"]["error"]["path"].endswith("broken.ply")
    assert "cannot read mesh" in recs["broken"]["error"]["reason"]
    for mid in rendered["meshes"]:
        assert recs[mid]["status"] == "ok"
        assert recs[mid]["n_views"] == 2
    # one Blender process for the whole batch: start-up reported exactly once
    assert sum("blender ready" in m for _, _, m in rendered["calls"]) == 1
    # progress reached the total, one message per model
    assert rendered["calls"][-1][0] == rendered["calls"][-1][1] == len(rendered["items"])


def test_ink_only_inside_projected_silhouette(rendered):
    for mid, mesh in rendered["meshes"].items():
        folder = model_out(rendered, mid)
        cams = read_json(folder / "cameras.json")
        assert cams["image_size"] == 128
        for i, view in enumerate(cams["views"]):
            P = np.array(view["projection"])
            uv = project(P, mesh.vertices)
            # rasterize projected triangles to the silhouette mask (pixel centres at i + 0.5)
            m8 = np.zeros((128, 128), np.uint8)
            for tri in mesh.faces:
                pts = np.round((uv[tri] - 0.5) * 16).astype(np.int32)
                cv2.fillConvexPoly(m8, pts, 1, lineType=cv2.LINE_8, shift=4)
            mask = ndimage.binary_dilation(m8 > 0, iterations=2)
            a = ink(folder, i)
            dark = a < 200
            assert dark.sum() > 50
            assert (dark & ~mask).sum() == 0, f"{mid} view {i}: ink outside the projected mesh"
            # silhouette bbox vs ink bbox within 2 px
            ys, xs = np.nonzero(a < 250)
            ink_box = np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1])
            proj_box = np.r_[uv.min(0), uv.max(0)]
            assert np.abs(ink_box - proj_box).max() <= 2.0, (mid, i, ink_box, proj_box)


def test_strokes_typed_and_on_ink(rendered):
    seen = set()
    for mid in rendered["meshes"]:
        folder = model_out(rendered, mid)
        strokes = read_json(folder / "strokes.json")
        assert len(strokes["views"]) == 2
        for i, view in enumerate(strokes["views"]):
            assert len(view) >= 1
            dist = ndimage.distance_transform_edt(ink(folder, i) >= 200)
            pts = np.concatenate([np.asarray(s["points"], float) for s in view])
            for s in view:
                seen.add(s["type"])
                assert len(s["points"]) >= 2
            px = np.clip(np.floor(pts).astype(int), 0, 127)
            near = dist[px[:, 1], px[:, 0]] <= 1.5
            assert near.mean() >= 0.95, f"{mid} view {i}: strokes off the ink ({near.mean():.2f})"
    assert "silhouette" in seen and "crease" in seen


def test_wedge_vertices_project_onto_ink(rendered):
    # every vertex of the convex prism is a corner of its drawing when visible; the hull corners
    # of its projection are always visible and must sit on ink
    mesh = rendered["meshes"]["wedge"]
    folder = model_out(rendered, "wedge")
    cams = read_json(folder / "cameras.json")
    for i, view in enumerate(cams["views"]):
        uv = project(np.array(view["projection"]), mesh.vertices)
        corners = uv[ConvexHull(uv).vertices]
        dist = ndimage.distance_transform_edt(ink(folder, i) >= 200)
        px = np.floor(corners).astype(int)
        assert (dist[px[:, 1], px[:, 0]] <= 1.5).all()


def test_restart_skips_done_models(rendered, monkeypatch):
    # every model has a record: no worker process may be started
    def boom(job):
        raise AssertionError("worker started for a finished batch")

    monkeypatch.setattr(batch_mod, "worker_command", boom)
    recs = render_batch(CATEGORY, rendered["items"], rendered["stage"], SETTINGS, SEED)
    assert [r["status"] for r in recs] == [r["status"] for r in rendered["records"]]


def test_worker_killed_fails_remaining_with_reason(tmp_path, monkeypatch, rendered):
    items = rendered["items"][:2]
    # a stand-in worker that speaks the progress protocol, starts the first model, then dies
    line = PROGRESS_PREFIX + json.dumps({"done": 0, "total": 2, "message": "x", "current": items[0][0]})
    kill = (
        "import os, signal, sys; print(%r, flush=True); sys.stderr.write('boom in render\\n');"
        " sys.stderr.flush(); os.kill(os.getpid(), signal.SIGKILL)" % line
    )
    monkeypatch.setattr(batch_mod, "worker_command", lambda job: [sys.executable, "-c", kill])
    recs = render_batch(CATEGORY, items, tmp_path, SETTINGS, SEED)
    for r in recs:
        assert r["status"] == "failed"
        assert "killed by signal SIGKILL" in r["error"]["reason"]
        assert "boom in render" in r["error"]["reason"]
    assert recs[0]["error"]["reason"].startswith("while rendering this model")
    assert recs[1]["error"]["reason"].startswith(f"while rendering model {items[0][0]}")
    with pytest.raises(RenderBatchError, match="SIGKILL"):
        render_batch(CATEGORY, items, tmp_path / "again", SETTINGS, SEED, on_crash="raise")
    assert not (tmp_path / "again" / CATEGORY / items[0][0] / "record.json").exists()


def test_worker_timeout_fails_remaining(tmp_path, monkeypatch, rendered):
    hang = "import time; time.sleep(60)"
    monkeypatch.setattr(batch_mod, "worker_command", lambda job: [sys.executable, "-c", hang])
    fast = RenderSettings(views=2, image_size=128, timeout_s=0.2, startup_timeout_s=0.3)
    recs = render_batch(CATEGORY, rendered["items"][:1], tmp_path, fast, SEED)
    assert recs[0]["status"] == "failed"
    assert "timed out after 0.5 s" in recs[0]["error"]["reason"]


def test_deterministic_bytes_and_partial_restart(rendered, tmp_path):
    items = [it for it in rendered["items"] if it[0] in ("box_cyl", "wedge")]
    render_batch(CATEGORY, items[:1], tmp_path, SETTINGS, SEED)
    first = (tmp_path / CATEGORY / "box_cyl" / "record.json").read_bytes()
    messages = []
    render_batch(CATEGORY, items, tmp_path, SETTINGS, SEED, progress=lambda d, t, m: messages.append(m))
    # the restarted batch rendered only the missing model
    assert (tmp_path / CATEGORY / "box_cyl" / "record.json").read_bytes() == first
    assert any("wedge rendering" in m for m in messages)
    assert not any("box_cyl rendering" in m for m in messages)
    for mid, _ in items:
        a, b = model_out(rendered, mid), tmp_path / CATEGORY / mid
        for name in ("view_00.png", "view_01.png", "strokes.json", "cameras.json"):
            assert (a / name).read_bytes() == (b / name).read_bytes(), f"{mid}/{name} differs"


def test_relative_paths_resolved(rendered, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    wedge = next(path for mid, path in rendered["items"] if mid == "wedge")
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "w.ply").write_bytes(wedge.read_bytes())
    one = RenderSettings(views=1, image_size=64)
    recs = render_batch(CATEGORY, [("w", Path("in/w.ply"))], Path("stage"), one, SEED)
    assert recs[0]["status"] == "ok", recs[0]
    assert (tmp_path / "stage" / CATEGORY / "w" / "view_00.png").exists()


def test_contact_sheet_from_stage(rendered, tmp_path):
    from workflows.sheets.render import main, sheet_from_stage

    plain = sheet_from_stage(rendered["stage"], per_category=3)
    over = sheet_from_stage(rendered["stage"], per_category=3, strokes=True)
    assert plain.shape == over.shape and plain.dtype == np.uint8
    # strokes overlaid in colour: red (silhouette) pixels appear only in the overlay
    red = lambda im: ((im[..., 0] > 150) & (im[..., 1] < 100)).sum()
    assert red(plain) == 0 and red(over) > 100
    assert plain.shape[0] > 3 * 128 and plain.shape[1] >= 2 * 128  # 3 models x 2 views
    out = tmp_path / "sheet.png"
    assert main(["--stage-dir", str(rendered["stage"]), "--out", str(out)]) == 0
    assert Image.open(out).size == (plain.shape[1], plain.shape[0])


def test_edge_types_setting_selects_what_is_drawn(rendered, tmp_path):
    """edge_types decides which Freestyle lines are drawn: the closed wedge has no borders, so
    drawing borders only leaves its views blank, while the defaults ink its outline."""
    with pytest.raises(ValueError, match="edge_types"):
        RenderSettings(edge_types=("silhouette", "outline"))
    wedge = [(mid, p) for mid, p in rendered["items"] if mid == "wedge"]
    s = RenderSettings(views=2, image_size=128, edge_types=("border",))
    render_batch(CATEGORY, wedge, tmp_path, s, SEED)
    borders = read_json(tmp_path / CATEGORY / "wedge" / "strokes.json")["views"]
    for i in range(2):
        assert borders[i] == [] and (ink(tmp_path / CATEGORY / "wedge", i) < 128).sum() == 0
        assert (ink(model_out(rendered, "wedge"), i) < 128).sum() > 100
