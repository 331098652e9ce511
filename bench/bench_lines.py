"""Line-fidelity benchmark: do the drawings show the source's sharp edges, and only real lines?

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_lines.py [--source procedural|FOLDER]
        [--per-category 3] [--views 4] [--work /tmp/lines] [--sheet docs/images/lines_before_after.png]

Per model: prepare (pipeline.prepare.batch), then render the same cameras twice: "before" draws the
watertight envelope ``mesh.ply`` (what the render stage drew until it read ``lines.ply``),
"after" draws ``lines.ply``, the cleaned source surface. Both drawings are scored against the
source mesh in the prepared frame (render.line_fidelity): sharp-edge recall (visible source
edges turning more than the render crease threshold, share within 2 px of ink) and precision
(share of ink within 2 px of a visible source contour, border or sharp edge), and as a check
the outline recall (visible source contours and borders within 2 px of ink). Medians over the
models of each category, with the triangles drawn and the render CPU seconds per view. ``--sheet`` writes a contact sheet: per model a row "before" then a row
"after", same views.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.core.atomic import read_json  # noqa: E402
from pipeline.core.images import save_png  # noqa: E402
from pipeline.core.records import read_record  # noqa: E402
from pipeline.core.schema import LINE_MESH_FILE, MESH_FILE  # noqa: E402
from pipeline.core.stage_keys import stage_key  # noqa: E402
from pipeline.prepare.batch import PrepareSettings, prepare_batch  # noqa: E402
from pipeline.prepare.line_mesh import line_mesh  # noqa: E402
from pipeline.sources.layouts import list_categories, list_models  # noqa: E402
from pipeline.sources.mesh_io import load_mesh  # noqa: E402
from render.batch import render_batch  # noqa: E402
from render.line_fidelity import ViewScore, score_view  # noqa: E402
from render.settings import RenderSettings  # noqa: E402
from workflows.sheets.render import sheet_of_rows  # noqa: E402

DRAWN = {"before": MESH_FILE, "after": LINE_MESH_FILE}


def _progress(done: int, total: int, message: str) -> None:
    print(f"  [{done}/{total}] {message}", file=sys.stderr, flush=True)


def model_scores(prep_dir: Path, render_dirs: dict[str, Path], turn_deg: float) -> dict[str, ViewScore]:
    """Summed view scores of one model's "before" and "after" drawings against its source."""
    rec = read_record(prep_dir)
    v, f = load_mesh(Path(rec["source"]["path"]), PrepareSettings().max_input_bytes)
    norm = rec["normalization"]
    # the reference is the full source surface (cleaned like lines.ply, never decimated)
    source = line_mesh(v, f, np.asarray(norm["center"]), float(norm["scale"]), max_faces=1 << 62)
    out = {}
    for name, folder in render_dirs.items():
        cams = read_json(folder / "cameras.json")["views"]
        total = ViewScore(0, 0, 0, 0)
        for i, cam in enumerate(cams):
            gray = np.asarray(Image.open(folder / f"view_{i:02d}.png").convert("L"))
            total = total + score_view(source, cam, gray, turn_deg)
        out[name] = total
    return out


def run(
    source: str,
    categories: list[str],
    per_category: int,
    work: Path,
    settings: RenderSettings,
    seed: int = 0,
    sheet_per_category: int = 1,
) -> tuple[dict, list]:
    prep_settings = PrepareSettings()
    prep_key = stage_key("prepare", prep_settings)
    results: dict[str, dict[str, list[ViewScore]]] = {}
    sheet_rows = []
    for cat in categories:
        refs = list_models(source, cat, per_category, seed, work)
        recs = prepare_batch(refs, work / prep_key, prep_settings, progress=_progress)
        ok = [r.model_id for r, rec in zip(refs, recs) if rec["status"] == "ok"]
        for r, rec in zip(refs, recs):
            if rec["status"] != "ok":
                print(f"{cat}/{r.model_id}: prepare failed: {rec['error']['reason']}", file=sys.stderr)
        stages = {}
        for name, file in DRAWN.items():
            stages[name] = work / f"lines-{name}-{stage_key('render', settings, prep_key)}"
            render_batch(
                cat,
                [(m, work / prep_key / cat / m / file) for m in ok],
                stages[name],
                settings,
                seed,
                progress=_progress,
            )
        results[cat] = {name: [] for name in DRAWN}
        for k, m in enumerate(ok):
            dirs = {name: stages[name] / cat / m for name in DRAWN}
            if any((read_record(d) or {}).get("status") != "ok" for d in dirs.values()):
                print(f"{cat}/{m}: render failed", file=sys.stderr)
                continue
            scores = model_scores(work / prep_key / cat / m, dirs, 180.0 - settings.crease_angle_deg)
            for name, s in scores.items():
                rec = read_record(dirs[name])
                s.faces, s.cpu_per_view = rec["mesh"]["n_faces"], statistics.median(rec["timings"]["views_cpu_s"])
                results[cat][name].append(s)
            print(
                f"{cat}/{m}: "
                + ", ".join(
                    f"{n} recall {s.recall:.3f} precision {s.precision:.3f} outline {s.outline_recall:.3f}"
                    for n, s in scores.items()
                ),
                flush=True,
            )
            for name, d in dirs.items() if k < sheet_per_category else ():
                views = sorted(d.glob("view_*.png"))
                sheet_rows.append(
                    [(np.asarray(Image.open(p).convert("L")), f"{cat}/{m} {name} v{i}") for i, p in enumerate(views)]
                )
    return results, sheet_rows


def table(results: dict) -> str:
    """Medians per category: recall, precision, triangles drawn and render CPU s per view."""
    lines = [
        "| category | models | sharp-edge recall before → after | precision before → after |"
        " outline recall before → after | triangles before → after | CPU s/view before → after |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for cat, by in results.items():
        if not by["after"]:
            continue
        med = {
            n: [
                statistics.median(getattr(s, k) for s in by[n])
                for k in ("recall", "precision", "outline_recall", "faces", "cpu_per_view")
            ]
            for n in DRAWN
        }
        b, a = med["before"], med["after"]
        lines.append(
            f"| {cat} | {len(by['after'])} | {b[0]:.3f} → **{a[0]:.3f}** | {b[1]:.3f} → **{a[1]:.3f}** |"
            f" {b[2]:.3f} → {a[2]:.3f} | {b[3]:.0f} → {a[3]:.0f} | {b[4]:.3f} → {a[4]:.3f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--source", default="procedural", help="procedural, a ShapeNet root or a folder of <category>/ meshes"
    )
    ap.add_argument("--categories", nargs="*", default=None)
    ap.add_argument("--per-category", type=int, default=3)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", type=Path, default=Path("work/bench-lines"))
    ap.add_argument("--sheet", type=Path, default=None, help="contact sheet PNG: before and after rows per model")
    ap.add_argument("--sheet-per-category", type=int, default=1, help="models per category on the sheet")
    args = ap.parse_args(argv)
    cats = args.categories or list_categories(args.source)
    settings = RenderSettings(views=args.views, image_size=args.size)
    results, rows = run(args.source, cats, args.per_category, args.work, settings, args.seed, args.sheet_per_category)
    print(
        f"\nsource {args.source}, {args.per_category} models per category, {args.views} views of"
        f" {args.size}², crease threshold {180.0 - settings.crease_angle_deg:.2f}° turn, tolerance 2 px;"
        " medians over models\n"
    )
    print(table(results))
    if args.sheet is not None and rows:
        save_png(args.sheet, sheet_of_rows(rows))
        print(f"\nsheet: {args.sheet}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
