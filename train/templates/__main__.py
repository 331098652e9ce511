"""CLI: ``python -m train.templates build`` (category templates + PNGs) and ``render``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from train.templates.build import DATA_DIR, BuildSettings, build_all, write_template_png
from train.templates.from_cuboids import TemplateSettings


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
    r = sub.add_parser("render", help="render a template to PNG, one colour per patch")
    r.add_argument("template", help="sphere24, sphere54, a category name, or a template .json path")
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--size", type=int, default=384, help="pixels per view (two views side by side)")
    args = ap.parse_args(argv)

    if args.cmd == "build":
        settings = BuildSettings(n_models=args.n_models, seed=args.seed, template=TemplateSettings(snap_tol=args.snap_tol))
        results = build_all(args.categories, args.out, settings, png=not args.no_png)
        for cat, res in results.items():
            t = res.template
            print(f"{cat}: {t.num_patches} patches, {t.num_params} parameters, median model {res.chosen}, "
                  f"optional {sorted(t.optional_parts)} -> {args.out / (cat + '.json')}")
        return 0
    from train.templates import load_template

    write_template_png(load_template(args.template), args.out, size=args.size)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
