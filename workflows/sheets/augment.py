"""Contact sheet of the augment stage: per model a row render → vector strokes → variants.

    python -m workflows.sheets.augment --render-dir WORK/render-<key> --out sheets/augment.png

Vector strokes are drawn one colour per stroke, so joins and splits are visible.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import cv2
import numpy as np

from augment.batch import list_views, load_gray
from augment.settings import AugmentSettings
from augment.variants import view_variants
from augment.vectorize import VectorizeError, vectorize
from pipeline.core.images import contact_sheet, save_png
from pipeline.core.records import read_record


def draw_strokes_color(strokes: list[np.ndarray], source_size: int, size: int) -> np.ndarray:
    """RGB (size, size) picture of the strokes, each in its own colour, thin and antialiased."""
    img = np.full((size, size, 3), 255, np.uint8)
    k = size / float(source_size)
    for i, s in enumerate(strokes):
        hue = (i * 47) % 180  # golden-ish hue steps keep neighbours apart
        color = cv2.cvtColor(np.uint8([[[hue, 220, 200]]]), cv2.COLOR_HSV2RGB)[0, 0].tolist()
        pts = np.round((np.asarray(s) * k - 0.5) * 16).astype(np.int32)
        cv2.polylines(img, [pts], False, color, 1, cv2.LINE_AA, 4)
        cv2.circle(img, tuple(int(x) for x in pts[0]), 2 * 16, color, -1, cv2.LINE_AA, 4)
    return img


def model_row(
    render_dir: Path, view: int, settings: AugmentSettings, seed: int, category: str, model_id: str
) -> tuple[list[np.ndarray], list[str]]:
    views = dict(list_views(render_dir))
    if view not in views:
        raise FileNotFoundError(f"{render_dir}: no view {view}")
    gray = load_gray(views[view])
    src = gray.shape[0]
    strokes = vectorize(gray, settings.vectorize)
    variants = view_variants(strokes, src, settings, (seed, category, model_id, view))
    size = settings.out_size
    images = [cv2.resize(gray, (size, size), interpolation=cv2.INTER_AREA), draw_strokes_color(strokes, src, size)] + [
        v.image for v in variants
    ]
    labels = [f"{category}/{model_id} v{view}", f"{len(strokes)} strokes"] + [
        f"var {k} w={v.width:.1f}" for k, v in enumerate(variants)
    ]
    return images, labels


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--render-dir", type=Path, required=True, help="render stage folder (<work>/render-<key>)")
    ap.add_argument("--out", type=Path, default=Path("sheets/augment.png"))
    ap.add_argument("--categories", default="", help="comma-separated; default all in the folder")
    ap.add_argument("--models", type=int, default=2, help="models per category")
    ap.add_argument("--view", type=int, default=0)
    ap.add_argument("--variants", type=int, default=4)
    ap.add_argument("--size", type=int, default=256, help="cell size (sketches drawn at this size)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    settings = dataclasses.replace(AugmentSettings(), variants=args.variants, out_size=args.size)
    cats = [c for c in args.categories.split(",") if c] or sorted(
        p.name for p in args.render_dir.iterdir() if p.is_dir() and not p.name.startswith(".")
    )
    images, labels = [], []
    for cat in cats:
        folders = sorted(
            p for p in (args.render_dir / cat).iterdir() if p.is_dir() and (read_record(p) or {}).get("status") == "ok"
        )
        for folder in folders[: args.models]:
            try:
                imgs, labs = model_row(folder, args.view, settings, args.seed, cat, folder.name)
            except (FileNotFoundError, VectorizeError) as e:
                print(f"skipped {folder}: {e}", file=sys.stderr)
                continue
            images += imgs
            labels += labs
    if not images:
        print(f"no rendered models under {args.render_dir}", file=sys.stderr)
        return 1
    save_png(args.out, contact_sheet(images, labels, cols=2 + args.variants))
    print(f"wrote {args.out} ({len(images) // (2 + args.variants)} rows)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
