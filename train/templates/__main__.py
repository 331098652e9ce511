"""CLI: ``python -m train.templates build`` (category templates + PNGs), ``render``, and ``sizes``
(patch count vs Chamfer to the median model, the measurement behind the patch budgets)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from train.templates.authoring.budget import PAPER_PATCHES, SHIPPED_PATCHES
from train.templates.authoring.build import DATA_DIR, BuildSettings, build_all, size_table
from train.templates.authoring.from_cuboids import TemplateSettings
from train.templates.authoring.user_cli import add_user_arguments, run_user_build

USER_DIR = Path("templates")  # relative to where the command runs: never the installed package

BUILD_HELP = """Build category templates from one of three inputs:

  --categories airplane ...      the built-in procedural categories (their generator's part boxes)
  --source DIR --category NAME   your meshes: DIR in any layout the pipeline reads (DIR/NAME/*.obj|glb|ply|...,
                                 ShapeNet); parts from the file's segmentation (OBJ g/o groups, glTF nodes,
                                 PLY face labels), else a <model>.pts + <model>.seg label file beside the mesh
                                 (ShapeNet-part), else connected components
  --cuboids FILE                 a YAML/JSON cuboid file written by hand or exported from CAD
                                 (format: train/templates/authoring/cuboid_file.py, docs/templates.md)

Writes <out>/<name>.json, .png and (user inputs) .report.txt; --out defaults to ./templates/ (a user
folder: train fit --template templates/NAME.json, or --template NAME run from this folder).
--shipped rebuilds the templates shipped in the package (train/templates/data/)."""


def _budget(text: str | None, categories: list[str]) -> dict[str, int] | None:
    """``shipped`` / ``paper`` → the shipped / the paper's counts; ``N`` → N for every category;
    ``cat=N,...`` → per category; ``none`` → no budget (the full construction)."""
    if text == "none":
        return None
    if text == "shipped":
        return {c: SHIPPED_PATCHES[c] for c in categories}
    if text == "paper":
        return {c: PAPER_PATCHES[c] for c in categories}
    if text.isdigit():
        return {c: int(text) for c in categories}
    try:
        return {k: int(v) for k, v in (item.split("=") for item in text.split(","))}
    except ValueError:
        raise SystemExit(f"--budget {text}: use paper, a number, or category=N,...") from None


def main(argv: list[str] | None = None) -> int:
    from pipeline.shapes import CATEGORIES

    ap = argparse.ArgumentParser(prog="python -m train.templates", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser(
        "build",
        help="build category templates: procedural categories, your meshes, or a cuboid file",
        description=BUILD_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    b.add_argument(
        "--categories",
        nargs="+",
        default=None,
        choices=CATEGORIES,
        help="built-in procedural categories (default: all eight, when neither --source nor --cuboids is given)",
    )
    b.add_argument("--n-models", type=int, default=16, help="models per category for the median")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument(
        "--snap-tol", type=float, default=TemplateSettings.snap_tol, help="lattice snapping (normalized units)"
    )
    b.add_argument(
        "--out", type=Path, default=None, help=f"output folder for <name>.json/.png (default: ./{USER_DIR}/)"
    )
    b.add_argument("--shipped", action="store_true", help=f"write into the package's shipped templates ({DATA_DIR})")
    b.add_argument("--no-png", action="store_true", help="skip the PNG renders")
    b.add_argument(
        "--budget",
        default=None,
        help="max patches: procedural categories 'shipped' (default: the paper's counts, airplane 84), 'paper', "
        "N, cat=N,..., or 'none'; --source/--cuboids: N or 'none' (default) "
        "(coarser lattice, small parts dropped, part labels merged; closest to the median wins)",
    )
    add_user_arguments(b)
    z = sub.add_parser("sizes", help="table: patch count vs Chamfer to the median model, per category")
    z.add_argument("--categories", nargs="+", default=list(CATEGORIES), choices=CATEGORIES)
    z.add_argument("--n-models", type=int, default=16)
    z.add_argument("--seed", type=int, default=0)
    r = sub.add_parser("render", help="render a template to PNG, one colour per patch")
    r.add_argument(
        "template",
        nargs="+",
        help="sphere24, sphere54, a category name, or a template .json path; "
        "several are rendered side by side (e.g. an old and a new template)",
    )
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--size", type=int, default=384, help="pixels per view (two views side by side)")
    args = ap.parse_args(argv)

    if args.cmd == "build":
        if args.shipped and args.out is not None:
            ap.error("--shipped and --out both name the output folder: give one")
        out = DATA_DIR if args.shipped else args.out if args.out is not None else USER_DIR
        if args.source is not None or args.cuboids is not None:
            if args.categories is not None:
                ap.error("--categories (procedural) cannot be combined with --source or --cuboids")
            if args.shipped:
                ap.error("--shipped is for the built-in categories; your templates go to --out (default ./templates/)")
            return run_user_build(args, out, ap.error)
        if args.category is not None:
            ap.error("--category names a category of --source (or a --cuboids template); procedural ones: --categories")
        args.categories = args.categories or list(CATEGORIES)
        args.out = out
        settings = BuildSettings(
            n_models=args.n_models,
            seed=args.seed,
            template=TemplateSettings(snap_tol=args.snap_tol),
            budget=_budget(args.budget or "shipped", args.categories),
        )
        results = build_all(args.categories, args.out, settings, png=not args.no_png)
        for cat, res in results.items():
            t = res.template
            print(
                f"{cat}: {t.num_patches} patches, {t.num_params} parameters, median model {res.chosen}, "
                f"Chamfer to it {t.metadata['chamfer_to_median']:.4f}, optional {t.part_names} -> {args.out / (cat + '.json')}"
            )
        return 0
    if args.cmd == "sizes":
        print(size_table(args.categories, BuildSettings(n_models=args.n_models, seed=args.seed)), end="")
        return 0
    import numpy as np

    from pipeline.core.images import save_png
    from train.templates import load_template
    from train.templates.render import render_template

    save_png(
        args.out, np.concatenate([render_template(load_template(t), size=args.size) for t in args.template], axis=1)
    )
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
