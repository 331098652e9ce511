"""Contact sheet of rendered views: one row per model, its views side by side.

    python -m workflows.sheets.render --stage-dir WORK/render-<key> --out sheets/renders.png
    python -m workflows.sheets.render --work-dir WORK --out sheets/renders.png      # newest render-* folder
    python -m workflows.sheets.render --procedural --work-dir WORK --per-category 2 --out sheets/renders.png

``--procedural`` first makes the inputs itself: procedural models → prepare stage → render stage
(all under WORK, in the stage folders a build with the same settings uses), then draws the sheet.
``--strokes`` overlays the captured Freestyle strokes (colour by edge type) on each view.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from pipeline.core.atomic import read_json
from pipeline.core.images import contact_sheet, save_png
from pipeline.core.records import model_dir, read_record
from pipeline.core.schema import LINE_MESH_FILE, STROKES_FILE, VIEW_GLOB
from pipeline.core.settings_io import add_arguments, from_args, setting
from workflows.build_settings import BuildSettings

TYPE_COLOURS = {"silhouette": (220, 30, 30), "border": (30, 120, 220), "crease": (20, 160, 60)}


def find_stage_dir(work_dir: Path) -> Path:
    stages = [p for p in Path(work_dir).glob("render-*") if p.is_dir()]
    if not stages:
        raise SystemExit(f"no render-* stage folder under {work_dir}")
    return max(stages, key=lambda p: (p.stat().st_mtime, p.name))


def overlay_strokes(gray: np.ndarray, strokes: list[dict]) -> np.ndarray:
    import cv2

    rgb = np.repeat(gray[..., None], 3, axis=2).copy()
    for s in strokes:
        pts = np.round(np.asarray(s["points"], float) * 16).astype(np.int32).reshape(-1, 1, 2)
        colour = TYPE_COLOURS.get(s["type"], (200, 120, 0))
        cv2.polylines(rgb, [pts], False, colour, 1, cv2.LINE_AA, shift=4)
    return rgb


def sheet_from_stage(stage_dir: Path, per_category: int = 3, max_views: int = 8, strokes: bool = False) -> np.ndarray:
    """Rows of up to ``max_views`` views for the first ``per_category`` rendered models of each category."""
    rows: list[list[tuple[np.ndarray, str]]] = []
    for cat_dir in sorted(p for p in Path(stage_dir).iterdir() if p.is_dir() and not p.name.startswith(".")):
        shown = 0
        for model in sorted(p for p in cat_dir.iterdir() if p.is_dir() and not p.name.startswith(".")):
            rec = read_record(model)
            if rec is None or rec.get("status") != "ok" or shown >= per_category:
                continue
            views = sorted(model.glob(VIEW_GLOB))[:max_views]
            stroke_views = read_json(model / STROKES_FILE)["views"] if strokes else None
            row = []
            for i, png in enumerate(views):
                gray = np.asarray(Image.open(png).convert("L"))
                row.append(
                    (overlay_strokes(gray, stroke_views[i]) if strokes else gray, f"{cat_dir.name}/{model.name} v{i}")
                )
            rows.append(row)
            shown += 1
    if not any(rows):
        raise SystemExit(f"no rendered models under {stage_dir}")
    return sheet_of_rows(rows)


def sheet_of_rows(rows: list[list[tuple[np.ndarray, str]]]) -> np.ndarray:
    """Contact sheet with one row per list of (image, label), padded with blank tiles."""
    cols = max(len(r) for r in rows)
    blank = np.full_like(next(r for r in rows if r)[0][0], 255)
    images = [img for r in rows for img, _ in r + [(blank, "")] * (cols - len(r))]
    labels = [lab for r in rows for _, lab in r + [("", "")] * (cols - len(r))]
    return contact_sheet(images, labels, cols=cols)


def render_procedural(build: BuildSettings, categories: list[str]) -> Path:
    """The build's models → prepare → render, into the build's stage folders; returns the render one."""
    from pipeline.prepare.batch import prepare_batch
    from render.batch import render_batch
    from workflows.listing import listed_models

    prep = build.stage_dir("prepare")
    for cat in categories:
        refs = listed_models(build, cat)
        records = prepare_batch(
            refs, prep, build.prepare_settings(), progress=_print_progress, parts=build.part_label_settings()
        )
        items = [
            (r.model_id, model_dir(prep, cat, r.model_id) / LINE_MESH_FILE)
            for r, rec in zip(refs, records)
            if rec.get("status") == "ok"
        ]
        render_batch(
            cat, items, build.stage_dir("render"), build.render_settings(), build.seed, progress=_print_progress
        )
    return build.stage_dir("render")


def _print_progress(done: int, total: int, message: str) -> None:
    print(f"[{done}/{total}] {message}", file=sys.stderr, flush=True)


@dataclasses.dataclass(frozen=True)
class RenderSheetSettings:
    stage_dir: Path | None = setting(None, "a render stage folder (render-<key>)")
    work_dir: Path | None = setting(None, "work folder: newest render-* inside, or output of --procedural")
    out: Path = setting(Path("sheets/renders.png"), "PNG to write")
    per_category: int = setting(3, "models per category (one row each)")
    max_views: int = setting(8, "views per row")
    strokes: bool = setting(False, "overlay captured strokes coloured by type")
    procedural: bool = setting(False, "make, prepare and render procedural models first")
    categories: tuple[str, ...] = setting((), "with --procedural (default: all)")
    seed: int = setting(0, "with --procedural: seeds the models")
    views: int = setting(BuildSettings.views, "with --procedural: views per model")
    image_size: int = setting(BuildSettings.image_size, "with --procedural: render size")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(ap, RenderSheetSettings)
    args = from_args(RenderSheetSettings, ap.parse_args(argv))

    if args.procedural:
        if args.work_dir is None:
            ap.error("--procedural needs --work-dir")
        from pipeline.shapes import CATEGORIES

        cats = list(args.categories) or list(CATEGORIES)
        build = BuildSettings(
            work_dir=args.work_dir,
            models_per_category=args.per_category,
            seed=args.seed,
            views=args.views,
            image_size=args.image_size,
        )
        stage = render_procedural(build, cats)
    elif args.stage_dir is not None:
        stage = args.stage_dir
    elif args.work_dir is not None:
        stage = find_stage_dir(args.work_dir)
    else:
        ap.error("give --stage-dir, --work-dir or --procedural --work-dir")
    sheet = sheet_from_stage(stage, args.per_category, args.max_views, args.strokes)
    save_png(args.out, sheet)
    print(f"wrote {args.out} ({sheet.shape[1]}x{sheet.shape[0]}) from {stage}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
