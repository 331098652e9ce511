"""CLI: ``python -m train.templates build`` (category templates + PNGs), ``render``, and ``sizes``
(patch count vs Chamfer to the median model, the measurement behind the patch budgets)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from train.templates.budget import PAPER_PATCHES, SHIPPED_PATCHES
from train.templates.build import DATA_DIR, BuildSettings, build_all, size_table
from train.templates.from_cuboids import TemplateSettings


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
    b = sub.add_parser("build", help="build category templates from procedural models")
    b.add_argument("--categories", nargs="+", default=list(CATEGORIES), choices=CATEGORIES)
    b.add_argument("--n-models", type=int, default=16, help="models per category for the median")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--snap-tol", type=float, default=TemplateSettings.snap_tol, help="lattice snapping (normalized units)")
    b.add_argument("--out", type=Path, default=DATA_DIR, help="output folder for <category>.json/.png")
    b.add_argument("--no-png", action="store_true", help="skip the PNG renders")
    b.add_argument("--budget", default="shipped",
                   help="max patches: 'shipped' (default: the paper's counts, airplane 84), 'paper', N, cat=N,..., or 'none' "
                   "(coarser lattice, small parts dropped, part labels merged; closest to the median wins)")
    z = sub.add_parser("sizes", help="table: patch count vs Chamfer to the median model, per category")
    z.add_argument("--categories", nargs="+", default=list(CATEGORIES), choices=CATEGORIES)
    z.add_argument("--n-models", type=int, default=16)
    z.add_argument("--seed", type=int, default=0)
    r = sub.add_parser("render", help="render a template to PNG, one colour per patch")
    r.add_argument("template", nargs="+", help="sphere24, sphere54, a category name, or a template .json path; "
                   "several are rendered side by side (e.g. an old and a new template)")
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--size", type=int, default=384, help="pixels per view (two views side by side)")
    args = ap.parse_args(argv)

    if args.cmd == "build":
        settings = BuildSettings(n_models=args.n_models, seed=args.seed, template=TemplateSettings(snap_tol=args.snap_tol),
                                 budget=_budget(args.budget, args.categories))  # fmt: skip
        results = build_all(args.categories, args.out, settings, png=not args.no_png)
        for cat, res in results.items():
            t = res.template
            print(f"{cat}: {t.num_patches} patches, {t.num_params} parameters, median model {res.chosen}, "
                  f"Chamfer to it {t.metadata['chamfer_to_median']:.4f}, optional {t.part_names} -> {args.out / (cat + '.json')}")
        return 0
    if args.cmd == "sizes":
        print(size_table(args.categories, BuildSettings(n_models=args.n_models, seed=args.seed)), end="")
        return 0
    from train.templates import load_template

    import numpy as np

    from pipeline.core.images import save_png
    from train.templates.render import render_template

    save_png(args.out, np.concatenate([render_template(load_template(t), size=args.size) for t in args.template], axis=1))
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
