"""augment_batch: rendered views → vectorized strokes → K pencil-sketch variants per view.

Reads ``view_XX.png`` from each model's render folder and vectorizes the *raster* (not the
captured Freestyle strokes: the point is that this works on any line drawing); the captured
``strokes.json``, when present, only serves as ground truth for the per-view vectorization
scores stored in the record. Writes per model ``sketch_<view>_<variant>.png``, ``strokes.json``
and, last, ``record.json``. Models with a record are skipped; a bad model gets a failed record,
a storage error fails the batch (pipeline.core.model_loop).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from PIL import Image

from augment.metrics import stroke_scores_at
from augment.settings import AugmentSettings
from augment.variants import view_variants
from augment.vectorize import VectorizeError, vectorize
from pipeline.core.atomic import read_json, write_json
from pipeline.core.errors import ModelError
from pipeline.core.images import save_png
from pipeline.core.model_loop import ModelJob, run_models
from pipeline.core.points_text import RoundedPoints
from pipeline.core.records import Progress, read_record
from pipeline.core.schema import STROKES_FILE, VIEW_GLOB, sketch_name, view_index


def list_views(render_dir: Path) -> list[tuple[int, Path]]:
    """(view index, path) of the rendered views, by index."""
    found = [(i, p) for p in Path(render_dir).glob(VIEW_GLOB) if (i := view_index(p.name)) is not None]
    return sorted(found)


def load_gray(path: Path) -> np.ndarray:
    """A PNG as uint8 grayscale (alpha composited on white); ModelError if unreadable."""
    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("RGBA", "LA", "P"):
                im = im.convert("RGBA")
                white = Image.new("RGBA", im.size, (255, 255, 255, 255))
                im = Image.alpha_composite(white, im)
            return np.asarray(im.convert("L"))
    except (OSError, ValueError) as e:
        raise ModelError(path, f"unreadable image: {e}") from e


def _captured(render_dir: Path) -> list | None:
    path = Path(render_dir) / STROKES_FILE
    if not path.exists():
        return None
    try:
        return read_json(path)["views"]
    except (OSError, ValueError, KeyError, TypeError):
        return None  # quality data only: a broken file must not fail the model


def augment_model(
    category: str, model_id: str, render_dir: Path, out_dir: Path, settings: AugmentSettings, seed: int
) -> dict:
    """Augment one model's views into ``out_dir``; returns the record fields. Raises ModelError."""
    render_dir = Path(render_dir)
    rec = read_record(render_dir)
    if rec is None:
        raise ModelError(render_dir, "no render record (render stage not finished)")
    if rec.get("status") != "ok":
        raise ModelError(render_dir, f"render stage failed: {rec.get('error')}")
    views = list_views(render_dir)
    if not views:
        raise ModelError(render_dir, "no view_XX.png images")
    captured = _captured(render_dir)
    t0 = time.perf_counter()
    doc_views, quality = [], []
    for view, path in views:
        gray = load_gray(path)
        h, w = gray.shape
        if h != w:
            raise ModelError(path, f"view is not square: {w}x{h}")
        try:
            strokes = vectorize(gray, settings.vectorize)
        except VectorizeError as e:
            raise ModelError(path, str(e)) from e
        if not strokes:
            raise ModelError(path, "blank view: no lines to vectorize")
        q: dict = {"view": view, "n_strokes": len(strokes)}
        if captured is not None and view < len(captured):
            ref = [np.asarray(s["points"], np.float64) for s in captured[view] if len(s["points"])]
            s2, s1 = stroke_scores_at(strokes, ref, w, (2.0, 1.0))
            q.update(
                precision=s2["precision"],
                recall=s2["recall"],
                f1=s2["f1"],
                f1_tol1=s1["f1"],
                n_captured=s2["n_ref"],
                count_ratio=s2["count_ratio"],
            )
        quality.append(q)
        variants = view_variants(strokes, w, settings, (seed, category, model_id, view))
        for k, var in enumerate(variants):
            save_png(Path(out_dir) / sketch_name(view, k), var.image)
        doc_views.append(
            {
                "view": view,
                "variants": [
                    {"variant": k, "width": round(var.width, 4), "strokes": RoundedPoints(var.strokes, 2)}
                    for k, var in enumerate(variants)
                ],
            }
        )
    write_json(
        Path(out_dir) / STROKES_FILE,
        {"out_size": settings.out_size, "source_size": w, "views": doc_views},
        compact=True,
    )
    f1s = [q["f1"] for q in quality if "f1" in q]
    return {
        "category": category,
        "model_id": model_id,
        "render_dir": str(render_dir),
        "views": len(views),
        "variants": settings.variants,
        "out_size": settings.out_size,
        "sketches": [sketch_name(v, k) for v, _ in views for k in range(settings.variants)],
        "vectorization": quality,
        "mean_f1": float(np.mean(f1s)) if f1s else None,
        "timings": {"augment_s": round(time.perf_counter() - t0, 4)},
    }


def augment_batch(
    category: str,
    items: list[tuple[str, Path]],
    stage_dir: Path,
    settings: AugmentSettings,
    seed: int,
    progress: Progress = None,
) -> list[dict]:
    """Augment every (model_id, render model folder); returns their records in order
    (pipeline.core.model_loop: a bad model is recorded, a storage error fails the batch)."""
    jobs = [ModelJob(category, model_id, Path(render_dir), Path(render_dir)) for model_id, render_dir in items]
    return run_models(
        "augment",
        stage_dir,
        jobs,
        lambda job, folder: augment_model(category, job.model_id, job.item, folder, settings, seed),
        progress,
    )
