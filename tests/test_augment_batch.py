"""augment_batch on hand-made render folders: outputs, records, skipping, determinism, bad input."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from augment.batch import augment_batch
from augment.settings import AugmentSettings
from pipeline.core.atomic import read_json, write_json
from pipeline.core.records import write_ok

SETTINGS = AugmentSettings(variants=3, out_size=64)
CAT = "testcat"


def fake_render(
    folder: Path, images: list[np.ndarray], strokes: list[list[np.ndarray]] | None, ok: bool = True
) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, img in enumerate(images):
        Image.fromarray(img).save(folder / f"view_{i:02d}.png")
    if strokes is not None:
        write_json(
            folder / "strokes.json",
            {"views": [[{"type": "silhouette", "points": s.tolist()} for s in view] for view in strokes]},
        )
    if ok:
        write_ok(folder, category=CAT)
    return folder


def line_drawing(k: int) -> tuple[np.ndarray, list[np.ndarray]]:
    img = np.full((128, 128), 255, np.uint8)
    box = np.array([[20.0, 20.0], [100.0 - 5 * k, 20.0], [100.0 - 5 * k, 90.0], [20.0, 90.0], [20.0, 20.0]])
    diag = np.array([[10.0, 120.0], [120.0, 10.0 + 5 * k]])
    for p in (box, diag):
        cv2.polylines(img, [np.round((p - 0.5) * 16).astype(np.int32)], False, 0, 2, cv2.LINE_AA, 4)
    return img, [box, diag]


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    root = tmp_path_factory.mktemp("aug")
    items = []
    for mid in ("m0", "m1"):
        views = [line_drawing(k) for k in range(2)]
        items.append((mid, fake_render(root / "render" / mid, [v[0] for v in views], [v[1] for v in views])))
    items.append(("blank", fake_render(root / "render" / "blank", [np.full((128, 128), 255, np.uint8)], None)))
    items.append(("black", fake_render(root / "render" / "black", [np.zeros((128, 128), np.uint8)], None)))
    items.append(("unrendered", fake_render(root / "render" / "unrendered", [line_drawing(0)[0]], None, ok=False)))
    return root, items


def run(root: Path, items, name: str, calls=None):
    progress = None if calls is None else (lambda d, t, m: calls.append((d, t, m)))
    return augment_batch(CAT, items, root / name, SETTINGS, seed=3, progress=progress)


def test_outputs_records_and_bad_models(renders):
    root, items = renders
    calls = []
    recs = run(root, items, "stage", calls)
    status = {mid: r["status"] for (mid, _), r in zip(items, recs)}
    assert status == {"m0": "ok", "m1": "ok", "blank": "failed", "black": "failed", "unrendered": "failed"}
    assert "blank" in recs[2]["error"]["reason"] and recs[2]["error"]["path"].endswith("view_00.png")
    assert "dark" in recs[3]["error"]["reason"]
    assert "render" in recs[4]["error"]["reason"]
    assert [c[:2] for c in calls] == [(i + 1, 5) for i in range(5)]

    out = root / "stage" / CAT / "m0"
    names = sorted(p.name for p in out.glob("sketch_*.png"))
    assert names == [f"sketch_{v:02d}_{k:02d}.png" for v in range(2) for k in range(3)]
    img = np.asarray(Image.open(out / "sketch_01_02.png"))
    assert img.shape == (64, 64) and img.dtype == np.uint8 and img.min() < 150
    doc = read_json(out / "strokes.json")
    assert doc["out_size"] == 64 and len(doc["views"]) == 2
    var = doc["views"][1]["variants"][2]
    assert var["width"] == pytest.approx(3.5 * 64 / 256)
    pts = np.concatenate([np.asarray(s) for s in var["strokes"]])
    assert pts.shape[1] == 2 and pts.max() < 70
    rec = read_json(out / "record.json")
    assert rec["status"] == "ok" and len(rec["vectorization"]) == 2
    assert all(q["f1"] >= 0.95 for q in rec["vectorization"]), rec["vectorization"]
    assert rec["mean_f1"] >= 0.95


def test_skips_done_models_and_is_deterministic(renders):
    root, items = renders
    run(root, items, "stage")
    out = root / "stage" / CAT / "m1"
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    calls = []
    run(root, items, "stage", calls)
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before
    # A fresh stage folder gives byte-identical sketches and strokes.
    run(root, items[:2], "again")
    for name in before:
        if name != "record.json":
            assert (out / name).read_bytes() == (root / "again" / CAT / "m1" / name).read_bytes(), name


def variants_digest() -> str:
    """sha256 over the sketches and strokes of one vectorized drawing's variants."""
    import hashlib

    from augment.variants import view_variants
    from augment.vectorize import vectorize

    img, _ = line_drawing(1)
    h = hashlib.sha256()
    for v in view_variants(vectorize(img), 128, AugmentSettings(variants=2, out_size=64), (3, "c", "m", 0)):
        h.update(v.image.tobytes())
        for s in v.strokes:
            h.update(np.ascontiguousarray(s).tobytes())
    return h.hexdigest()


def test_same_output_in_another_process():
    import os
    import subprocess
    import sys

    root = str(Path(__file__).resolve().parents[1])
    # another interpreter with another hash seed: nothing may depend on set order or id()
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    script = f"import sys; sys.path.insert(0, {root!r}); from tests.test_augment_batch import variants_digest; print(variants_digest())"
    out = subprocess.run([sys.executable, "-c", script], env=env, cwd=root, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == variants_digest()
