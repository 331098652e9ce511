"""Contact sheet of raw procedural shapes: one row per category.

python -m pipeline.sheets.shapes --out sheets/shapes.png --per-category 6 --seed 0
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from pipeline.core.images import contact_sheet, save_png
from pipeline.core.settings_io import add_arguments, from_args, setting
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


@dataclasses.dataclass(frozen=True)
class ShapesSheetSettings:
    out: Path = setting(Path("sheets/shapes.png"), "PNG to write")
    per_category: int = setting(6, "models per category (one row each category)")
    seed: int = setting(0, "seeds the procedural generator")
    size: int = setting(192, "thumbnail size in pixels")
    categories: tuple[str, ...] = setting(CATEGORIES, "the categories drawn", choices=CATEGORIES)
    defect_fraction: float = setting(0.25, "share of models given deliberate mesh defects")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(ap, ShapesSheetSettings)
    a = from_args(ShapesSheetSettings, ap.parse_args(argv))
    sheet = build_sheet(a.per_category, a.seed, a.size, list(a.categories), a.defect_fraction)
    save_png(a.out, sheet)
    print(f"wrote {a.out} ({sheet.shape[1]}x{sheet.shape[0]})")


if __name__ == "__main__":
    main()
