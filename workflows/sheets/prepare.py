"""Contact sheet of raw vs prepared shapes: per category a row of (raw, prepared) pairs.

    .venv/bin/python -m workflows.sheets.prepare --out sheets/prepared.png --per-category 3

Models are prepared (or reused, if already prepared) under ``--work``, in the prepare stage folder
a build with the same settings uses (``BuildSettings.stage_dir``); raw thumbnails are drawn from
the source files, prepared ones from mesh.ply, both by the CPU thumbnail renderer.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from pipeline.core.errors import ModelError
from pipeline.core.images import contact_sheet, save_png
from pipeline.core.schema import MESH_FILE
from pipeline.core.thumbnails import render_mesh
from pipeline.prepare.batch import PrepareSettings, prepare_batch
from pipeline.sources.layouts import list_categories
from pipeline.sources.mesh_io import load_mesh, read_ply
from workflows.build_settings import BuildSettings
from workflows.listing import listed_models

RAW_COLOR = (0.85, 0.72, 0.6)
PREPARED_COLOR = (0.62, 0.74, 0.88)
VIEWS = {"mug": (120.0, 25.0), "guitar": (25.0, 15.0), "gun": (60.0, 15.0), "knife": (60.0, 20.0)}


def _thumb(vertices: np.ndarray, faces: np.ndarray, color, size: int, category: str) -> np.ndarray:
    az, el = VIEWS.get(category, (30.0, 20.0))
    return render_mesh(vertices, faces, size=size, azimuth_deg=az, elevation_deg=el, face_colors=np.array(color))


def build_sheet(build: BuildSettings, size: int, categories: list[str]) -> np.ndarray:
    """Prepare the first ``build.models_per_category`` models of each category (as the build does,
    into its prepare stage folder) and draw raw/prepared pairs."""
    stage, settings, per_category = build.stage_dir("prepare"), build.prepare_settings(), build.models_per_category
    blank = np.full((size, size, 3), 255, np.uint8)
    images, labels = [], []
    for cat in categories:
        refs = listed_models(build, cat)
        records = prepare_batch(refs, stage, settings)
        for ref, rec in zip(refs, records):
            try:
                v, f = load_mesh(ref.path, settings.max_input_bytes)
                images.append(_thumb(v, f, RAW_COLOR, size, cat))
                labels.append(f"{cat} {ref.model_id} raw {len(f)}f")
            except ModelError as err:
                images.append(blank)
                labels.append(f"{cat} {ref.model_id} raw: {err.reason}")
            if rec["status"] == "ok":
                v, f = read_ply(stage / cat / ref.model_id / MESH_FILE)
                images.append(_thumb(v, f, PREPARED_COLOR, size, cat))
                labels.append(f"prepared {len(f)}f")
            else:
                images.append(blank)
                labels.append(f"FAILED: {rec['error']['reason']}")
        # Pad short categories so each category keeps its own row.
        for _ in range(2 * (per_category - len(refs))):
            images.append(blank)
            labels.append("")
    return contact_sheet(images, labels, cols=2 * per_category)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("sheets/prepared.png"))
    ap.add_argument(
        "--source", default="procedural", help="'procedural', a ShapeNet v2 root or a <root>/<category>/ folder"
    )
    ap.add_argument("--work", type=Path, default=Path("work"), help="work dir for sources and prepared meshes")
    ap.add_argument("--per-category", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=160, help="thumbnail size in pixels")
    ap.add_argument("--categories", nargs="*", default=None, help="default: all categories of the source")
    ap.add_argument("--resolution", type=int, default=PrepareSettings.resolution)
    ap.add_argument("--max-faces", type=int, default=PrepareSettings.max_faces)
    args = ap.parse_args(argv)
    if args.per_category < 1:
        ap.error("--per-category must be >= 1")
    build = BuildSettings(
        source=args.source,
        work_dir=args.work,
        models_per_category=args.per_category,
        seed=args.seed,
        prepare_overrides=json.dumps({"resolution": args.resolution, "max_faces": args.max_faces}),
    )
    categories = args.categories or list_categories(args.source)
    sheet = build_sheet(build, args.size, categories)
    save_png(args.out, sheet)
    print(f"wrote {args.out} ({sheet.shape[1]}x{sheet.shape[0]})")


if __name__ == "__main__":
    main()
