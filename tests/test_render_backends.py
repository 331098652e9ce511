"""The embree contour backend (render.edge_lines) against Freestyle: same files, the same strokes
within 2 px (F1 >= 0.95) on prepared procedural models, byte-identical re-runs, Freestyle the
default, and a Luigi build that takes the backend from --render-settings."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from augment.metrics import stroke_scores
from pipeline.core.atomic import read_json
from render.batch import render_batch
from render.edge_lines import draw_strokes
from render.settings import RenderSettings
from workflows.build_settings import BuildSettings

ROOT = Path(__file__).resolve().parents[1]
CATEGORIES = ("airplane", "car", "mug")
VIEWS = 2
MIXED = "mixed"  # one category folder holding a model of each category
SEED = 3


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """One prepared model per category, drawn by both backends at the default 256² (one batch
    per backend: a single Blender start)."""
    from pipeline.prepare.batch import PrepareSettings, prepare_batch
    from pipeline.sources.layouts import list_models

    work = tmp_path_factory.mktemp("backends")
    items = []
    for cat in CATEGORIES:
        refs = list_models("procedural", cat, 1, 0, work)
        rec = prepare_batch(refs, work / "prepare", PrepareSettings())[0]
        assert rec["status"] == "ok", rec
        items.append((f"{cat}_{refs[0].model_id}", work / "prepare" / cat / refs[0].model_id / "mesh.ply"))
    for backend in ("freestyle", "embree"):
        recs = render_batch(MIXED, items, work / backend, RenderSettings(views=VIEWS, backend=backend), SEED)
        assert [r["status"] for r in recs] == ["ok"] * len(items), recs
    return items, {mid: (work / "freestyle" / MIXED / mid, work / "embree" / MIXED / mid) for mid, _ in items}


def strokes_of(folder: Path) -> list[list[np.ndarray]]:
    return [[np.asarray(s["points"], float) for s in view] for view in read_json(folder / "strokes.json")["views"]]


def test_default_backend_is_freestyle_and_keys_differ() -> None:
    assert RenderSettings().backend == "freestyle"
    assert BuildSettings().render_settings().backend == "freestyle"
    fast = BuildSettings(render_overrides='{"backend": "embree"}')
    assert fast.render_settings().backend == "embree"
    assert fast.prepare_key() == BuildSettings().prepare_key()
    assert fast.render_key() != BuildSettings().render_key()
    assert fast.augment_key() != BuildSettings().augment_key()
    with pytest.raises(ValueError, match="backend must be one of"):
        RenderSettings(backend="lineart")


def test_same_files_and_formats(rendered) -> None:
    _, models = rendered
    for cat, (fs, em) in models.items():
        assert sorted(p.name for p in fs.iterdir()) == sorted(p.name for p in em.iterdir())
        assert (fs / "cameras.json").read_bytes() == (em / "cameras.json").read_bytes()
        for i in range(VIEWS):
            a, b = Image.open(fs / f"view_{i:02d}.png"), Image.open(em / f"view_{i:02d}.png")
            assert (a.mode, a.size) == (b.mode, b.size) == ("L", (256, 256))
        doc = read_json(em / "strokes.json")
        assert doc["image_size"] == 256 and len(doc["views"]) == VIEWS
        types = {s["type"] for view in doc["views"] for s in view}
        assert "silhouette" in types and types <= {"silhouette", "border", "crease"}
        assert all(s["type"] in s["types"] and len(s["points"]) >= 2 for view in doc["views"] for s in view)


def test_embree_strokes_match_freestyle(rendered) -> None:
    _, models = rendered
    for cat, (fs, em) in models.items():
        for i, (ref, got) in enumerate(zip(strokes_of(fs), strokes_of(em))):
            score = stroke_scores(got, ref, 256, tol=2.0)
            assert score["f1"] >= 0.95, (cat, i, score)
            # the drawing is the strokes drawn 1.5 px wide, as Freestyle draws its own
            ink = np.asarray(Image.open(em / f"view_{i:02d}.png"))
            assert np.array_equal(ink, draw_strokes(got, 256, 1.5))
            fs_ink = (np.asarray(Image.open(fs / f"view_{i:02d}.png")) < 128).sum()
            assert 0.85 <= (ink < 128).sum() / fs_ink <= 1.3, (cat, i)


def test_embree_deterministic(rendered, tmp_path) -> None:
    items, models = rendered
    render_batch(MIXED, items, tmp_path, RenderSettings(views=VIEWS, backend="embree"), SEED)
    for mid, (_, em) in models.items():
        again = tmp_path / MIXED / mid
        for name in ["strokes.json", "cameras.json"] + [f"view_{i:02d}.png" for i in range(VIEWS)]:
            assert (again / name).read_bytes() == (em / name).read_bytes(), (mid, name)


def test_draw_strokes_width() -> None:
    # a horizontal line 1.5 px wide through pixel centres' row 10.5 inks rows whose centre is
    # within 0.75 px: exactly row 10 (centres at 9.5 and 11.5 are 1 px away)
    img = draw_strokes([np.array([[2.0, 10.5], [30.0, 10.5]])], 32, 1.5)
    rows = np.flatnonzero((img < 128).any(axis=1))
    assert rows.tolist() == [10]
    img = draw_strokes([np.array([[2.0, 11.0], [30.0, 11.0]])], 32, 1.5)
    assert np.flatnonzero((img < 128).any(axis=1)).tolist() == [10, 11]
    assert draw_strokes([], 16, 1.5).min() == 255


def test_luigi_build_with_embree_backend(tmp_path) -> None:
    settings = json.dumps({"backend": "embree"})
    cmd = [
        str(Path(sys.executable).parent / "luigi"),
        "--module",
        "workflows",
        "BuildDataset",
        "--local-scheduler",
        "--categories",
        "mug",
        "--models-per-category",
        "2",
        "--views",
        "2",
        "--variants",
        "1",
        "--image-size",
        "64",
        "--out-size",
        "64",
        "--render-settings",
        settings,
        "--work-dir",
        str(tmp_path / "work"),
        "--dataset-dir",
        str(tmp_path / "ds"),
    ]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT)] + [p for p in [os.environ.get("PYTHONPATH")] if p])}
    run = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    manifest = read_json(tmp_path / "ds" / "manifest.json")
    mug = manifest["categories"]["mug"]
    assert mug["models_built"] == 2
    s = BuildSettings(
        models_per_category=2,
        views=2,
        variants=1,
        image_size=64,
        out_size=64,
        render_overrides=settings,
        work_dir=tmp_path / "work",
    )
    render_dir = s.stage_dir("render")
    assert render_dir.is_dir()
    recs = [read_json(p) for p in sorted(render_dir.glob("mug/*/record.json"))]
    assert len(recs) == 2 and all(r["status"] == "ok" for r in recs)


def test_embree_draws_only_the_edge_types_asked_for() -> None:
    # a cube seen from above a corner: its outline is silhouette, the three edges meeting at the
    # near corner are creases; each kind is drawn only when edge_types names it
    import trimesh

    from render.cameras import make_view
    from render.edge_lines import CREASE, SILHOUETTE, MeshLines

    cube = trimesh.creation.box((0.8, 0.8, 0.8))

    def natures(kinds: tuple[str, ...]) -> set[int]:
        settings = RenderSettings(backend="embree", edge_types=kinds)
        lines = MeshLines(np.asarray(cube.vertices), np.asarray(cube.faces), settings)
        return set(lines.feature_edges(make_view(settings, 30.0, 30.0))[1].tolist())

    assert natures(RenderSettings().edge_types) == {SILHOUETTE, CREASE}
    assert natures(("silhouette", "border")) == {SILHOUETTE}
    assert natures(("external_contour",)) == {SILHOUETTE}
    assert natures(("crease",)) == {CREASE}


def test_embree_refuses_edge_types_it_cannot_draw() -> None:
    with pytest.raises(ValueError, match="embree backend draws only"):
        RenderSettings(backend="embree", edge_types=("suggestive_contour", "ridge_valley"))
    RenderSettings(backend="freestyle", edge_types=("suggestive_contour",))  # Freestyle draws them
    RenderSettings(backend="embree", edge_types=("suggestive_contour", "crease"))  # the crease it draws
