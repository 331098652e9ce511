"""Contact sheet of raw procedural shapes: one row per category.

python -m pipeline.sheets.shapes --out sheets/shapes.png --per-category 6 --seed 0
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pipeline.core.images import contact_sheet, save_png
from pipeline.core.thumbnails import render_mesh
from pipeline.shapes import CATEGORIES, generate

# Distinct muted colours per part so the part structure is visible.
_PALETTE = np.array(
    [
        [200, 205, 220],
        [230, 160, 120],
        [140, 190, 150],
        [220, 200, 120],
        [160, 170, 230],
        [210, 150, 190],
        [130, 200, 210],
        [200, 180, 160],
        [170, 210, 120],
        [230, 130, 130],
    ],
    np.uint8,
)


def model_thumbnail(model, size: int = 192, azimuth_deg: float = 30, elevation_deg: float = 20) -> np.ndarray:
    v, f = model.merged()
    colors = np.concatenate(
        [np.tile(_PALETTE[i % len(_PALETTE)], (len(p.faces), 1)) for i, p in enumerate(model.parts)]
    )
    return render_mesh(v, f, size=size, azimuth_deg=azimuth_deg, elevation_deg=elevation_deg, face_colors=colors)


# Views that show each category's telling parts (e.g. the mug handle sits on the +z side).
VIEWS = {"mug": (120.0, 25.0), "guitar": (25.0, 15.0), "gun": (60.0, 15.0), "knife": (60.0, 20.0)}


def build_sheet(
    per_category: int, seed: int, size: int = 192, categories=CATEGORIES, defect_fraction: float = 0.25
) -> np.ndarray:
    images, labels = [], []
    for cat in categories:
        for i in range(per_category):
            m = generate(cat, i, seed=seed, defect_fraction=defect_fraction)
            images.append(model_thumbnail(m, size, *VIEWS.get(cat, (30.0, 20.0))))
            tag = f" [{len(m.defects)} defect{'s' * (len(m.defects) > 1)}]" if m.defects else ""
            labels.append(f"{cat} {m.model_id} {m.n_faces}f{tag}")
    return contact_sheet(images, labels, cols=per_category)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("sheets/shapes.png"))
    ap.add_argument("--per-category", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=192, help="thumbnail size in pixels")
    ap.add_argument("--categories", nargs="*", default=list(CATEGORIES))
    ap.add_argument("--defect-fraction", type=float, default=0.25)
    args = ap.parse_args(argv)
    sheet = build_sheet(args.per_category, args.seed, args.size, args.categories, args.defect_fraction)
    save_png(args.out, sheet)
    print(f"wrote {args.out} ({sheet.shape[1]}x{sheet.shape[0]})")


if __name__ == "__main__":
    main()
