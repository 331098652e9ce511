"""Vectorization of real Freestyle renders, scored against the strokes Freestyle captured.

Fast: the three small test meshes (box on cylinder, capsule, wedge), rendered once per module.
Slow: procedural models of several categories (prepare + render + augment).
"""

from __future__ import annotations

import numpy as np
import pytest

from augment.batch import augment_batch
from augment.settings import AugmentSettings
from render.batch import render_batch
from render.sample_meshes import write_samples
from render.settings import RenderSettings

RENDER = RenderSettings(views=3, image_size=256)


def check_records(records: list[dict], min_f1: float = 0.95) -> list[float]:
    f1s = []
    for rec in records:
        assert rec["status"] == "ok", rec
        for q in rec["vectorization"]:
            assert q["f1"] >= min_f1, (rec["model_id"], q)
            assert q["precision"] >= 0.95 and q["recall"] >= 0.9, (rec["model_id"], q)
            # Freestyle often captures a line as many tiny pieces (200 for an airplane view);
            # the vectorizer joins them, so only an excess of strokes would be a defect.
            assert 0 < q["count_ratio"] <= 5.0
            f1s.append(q["f1"])
    return f1s


@pytest.fixture(scope="module")
def sample_renders(tmp_path_factory):
    root = tmp_path_factory.mktemp("augrender")
    items = write_samples(root / "meshes")
    recs = render_batch("samples", items, root / "render", RENDER, seed=1)
    assert all(r["status"] == "ok" for r in recs), recs
    return root, [(mid, root / "render" / "samples" / mid) for mid, _ in items]


def test_vectorization_f1_on_sample_renders(sample_renders):
    root, items = sample_renders
    recs = augment_batch("samples", items, root / "augment", AugmentSettings(variants=2), seed=0)
    f1s = check_records(recs)
    assert np.mean(f1s) >= 0.97
    folder = root / "augment" / "samples" / items[0][0]
    assert len(list(folder.glob("sketch_*.png"))) == 3 * 2


@pytest.mark.slow
def test_vectorization_f1_on_procedural_categories(tmp_path):
    from pipeline.prepare.batch import prepare_batch
    from pipeline.prepare.settings import PrepareSettings
    from pipeline.sources.layouts import list_models

    f1s = []
    for cat in ("airplane", "car", "mug", "guitar", "knife"):
        refs = list_models("procedural", cat, 2, 0, tmp_path)
        prep = prepare_batch(refs, tmp_path / "prep", PrepareSettings())
        items = [
            (r.model_id, tmp_path / "prep" / cat / r.model_id / "mesh.ply")
            for r, rec in zip(refs, prep)
            if rec["status"] == "ok"
        ]
        assert items, cat
        render_batch(cat, items, tmp_path / "render", RENDER, seed=0)
        recs = augment_batch(
            cat,
            [(mid, tmp_path / "render" / cat / mid) for mid, _ in items],
            tmp_path / "augment",
            AugmentSettings(variants=1),
            seed=0,
        )
        f1s += check_records(recs)
    assert np.mean(f1s) >= 0.97


def test_contact_sheet(sample_renders, tmp_path):
    from PIL import Image

    from workflows.sheets.augment import main

    root, _ = sample_renders
    out = tmp_path / "sheet.png"
    assert (
        main(
            [
                "--render-dir",
                str(root / "render"),
                "--out",
                str(out),
                "--variants",
                "2",
                "--size",
                "96",
                "--models",
                "3",
            ]
        )
        == 0
    )
    sheet = np.asarray(Image.open(out))
    # 3 models → 3 rows of (render, strokes, 2 variants) cells of 96 px plus labels.
    assert sheet.shape[0] > 3 * 96 and sheet.shape[1] > 4 * 96 and sheet.shape[1] < 5 * 96
    assert sheet.min() < 100  # something was drawn
