"""CLI: ``python -m train.templates build`` (category templates + PNGs), ``render``, and ``sizes``
(patch count vs Chamfer to the median model, the measurement behind the patch budgets)."""

from __future__ import annotations

import argparse
import sys

from pipeline.core.settings_io import SettingError, add_arguments, from_args
from train.templates.authoring.commands import (
    CommandError,
    TemplatesBuildSettings,
    TemplatesRenderSettings,
    TemplatesSizesSettings,
    run_procedural_build,
    run_user_build,
)

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


def _build(s: TemplatesBuildSettings) -> int:
    out = s.out_dir()
    return run_user_build(s, out) if s.user_input else run_procedural_build(s, out)


def _sizes(s: TemplatesSizesSettings) -> int:
    from train.templates.authoring.build import BuildSettings, size_table

    print(size_table(list(s.categories), BuildSettings(n_models=s.n_models, seed=s.seed)), end="")
    return 0


def _render(s: TemplatesRenderSettings) -> int:
    import numpy as np

    from pipeline.core.images import save_png
    from train.templates import load_template
    from train.templates.render import render_template

    save_png(s.out, np.concatenate([render_template(load_template(t), size=s.size) for t in s.template], axis=1))
    print(s.out)
    return 0


COMMANDS = {
    "build": (TemplatesBuildSettings, _build),
    "sizes": (TemplatesSizesSettings, _sizes),
    "render": (TemplatesRenderSettings, _render),
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m train.templates", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    parsers = {
        "build": sub.add_parser(
            "build",
            help="build category templates: procedural categories, your meshes, or a cuboid file",
            description=BUILD_HELP,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        ),
        "sizes": sub.add_parser("sizes", help="table: patch count vs Chamfer to the median model, per category"),
        "render": sub.add_parser("render", help="render a template to PNG, one colour per patch"),
    }
    for name, (cls, _) in COMMANDS.items():
        add_arguments(parsers[name], cls)
    args = ap.parse_args(argv)
    cls, run = COMMANDS[args.cmd]
    try:
        return run(from_args(cls, args))
    except (CommandError, SettingError) as exc:
        parsers[args.cmd].error(str(exc))


if __name__ == "__main__":
    sys.exit(main())
