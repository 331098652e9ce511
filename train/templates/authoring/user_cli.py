"""``templates build --source DIR --category NAME`` / ``--cuboids FILE``: the flags and the run."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Callable

from train.templates.authoring.symmetry import MIRROR_TOL


def _hollow(text: str) -> tuple[str, tuple[float, float]]:
    """``LABEL`` or ``LABEL=WALL,BOTTOM`` (fractions, as the built-in mug: 0.12,0.12)."""
    label, _, fr = text.partition("=")
    try:
        wall, bottom = (float(x) for x in fr.split(",")) if fr else (0.12, 0.12)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--hollow {text}: use LABEL or LABEL=WALL,BOTTOM") from None
    return label.strip(), (wall, bottom)


def _group(text: str) -> tuple[str, list[str]]:
    name, _, labels = text.partition("=")
    if not labels:
        raise argparse.ArgumentTypeError(f"--part-group {text}: use NAME=LABEL,LABEL,...")
    return name.strip(), [x.strip() for x in labels.split(",") if x.strip()]


def add_user_arguments(b: argparse.ArgumentParser) -> None:
    g = b.add_argument_group("your own category (--source or --cuboids)")
    g.add_argument("--source", help="a folder source (DIR/NAME/*.obj ..., or ShapeNet) whose category NAME to build")
    g.add_argument(
        "--category",
        help="the category (folder) in --source; the template's name (--cuboids: "
        "default the file's 'category', else its file name)",
    )
    g.add_argument("--cuboids", type=Path, help="a cuboid file (YAML/JSON, see docs/templates.md)")
    g.add_argument("--limit", type=int, default=None, help="--source: read at most this many models")
    g.add_argument(
        "--part-map", type=Path, help="YAML/JSON {name or glob: common name or null} renaming parts across models"
    )
    g.add_argument(
        "--labels-dir", type=Path, help="folder with points/<id>.pts + points_label/<id>.seg (ShapeNet-part)"
    )
    g.add_argument("--components", action="store_true", help="ignore segmentations: one part per connected component")
    g.add_argument(
        "--min-part-size",
        type=float,
        default=None,
        help="drop components whose largest extent is under this fraction of the model's size (default 0.04)",
    )
    g.add_argument("--max-parts", type=int, default=None, help="boxes kept per model, largest first (default 32)")
    g.add_argument(
        "--presence-threshold",
        type=float,
        default=1.0,
        help="a part in at least this share of the models is required, in fewer optional (default 1: "
        "every part some model lacks is optional)",
    )
    g.add_argument("--min-presence", type=float, default=0.0, help="parts in fewer models than this share are dropped")
    g.add_argument(
        "--symmetry",
        choices=("auto", "x", "none"),
        default=None,
        help="mirror plane x = 0: auto (default: when the median's boxes pair up), x (force), none",
    )
    g.add_argument(
        "--mirror-tol", type=float, default=MIRROR_TOL, help="how far (normalized units) mirror boxes may differ"
    )
    g.add_argument(
        "--hollow",
        type=_hollow,
        action="append",
        default=[],
        metavar="LABEL[=WALL,BOTTOM]",
        help="build this part as a floor + four walls open at +y (a cup, a tub); repeatable",
    )
    g.add_argument(
        "--part-group",
        type=_group,
        action="append",
        default=[],
        metavar="NAME=LABEL,...",
        help="labels whose Chamfer/normal terms are computed apart (the paper's car wheels); repeatable",
    )
    g.add_argument(
        "--strict", action="store_true", help="--source: stop at the first unusable model instead of skipping it"
    )


def run_user_build(args: argparse.Namespace, out: Path, error: Callable[[str], None]) -> int:
    from pipeline.core.atomic import write_bytes
    from pipeline.sources.part_names import PartMapError, read_part_map
    from train.templates.authoring.build import write_template_png
    from train.templates.authoring.cuboid_file import CuboidFileError, file_models, read_cuboid_file
    from train.templates.authoring.mesh_boxes import PartSettings, source_models
    from train.templates.authoring.user import TemplateInputError, UserSettings, build_user_template
    from train.templates.template import save_template

    if (args.source is None) == (args.cuboids is None):
        error("give --source DIR --category NAME, or --cuboids FILE (not both)")
    budget = None
    if args.budget not in (None, "none"):
        if not str(args.budget).isdigit():
            error(f"--budget {args.budget}: with --source/--cuboids use a number or 'none'")
        budget = int(args.budget)
    try:
        hollow, groups, symmetry, skipped = dict(args.hollow), dict(args.part_group), args.symmetry or "auto", {}
        if args.cuboids is not None:
            cf = read_cuboid_file(args.cuboids)
            name = args.category or cf.category or args.cuboids.stem
            models = file_models(cf, seed=args.seed)
            hollow, groups = {**cf.hollow, **hollow}, {**cf.part_groups, **groups}
            symmetry = args.symmetry or cf.symmetry
        else:
            if not args.category:
                error("--source needs --category NAME (a folder of the source)")
            name = args.category
            defaults = PartSettings()
            ps = PartSettings(
                min_part_size=defaults.min_part_size if args.min_part_size is None else args.min_part_size,
                max_parts=args.max_parts or defaults.max_parts,
                use_segmentation=not args.components,
            )
            part_map = read_part_map(args.part_map) if args.part_map else None
            models, skipped = source_models(
                args.source,
                name,
                ps,
                args.seed,
                args.limit,
                part_map,
                args.labels_dir,
                args.strict,
                progress=lambda n, mid: print(f"[{n}] {mid}", file=sys.stderr, flush=True),
            )
        settings = UserSettings(
            presence_threshold=args.presence_threshold,
            min_presence=args.min_presence,
            snap_tol=args.snap_tol,
            symmetry=symmetry,
            mirror_tol=args.mirror_tol,
            budget=budget,
            hollow=hollow,
            part_groups=groups,
            seed=args.seed,
        )
        res = build_user_template(models, name, settings, skipped)
    except (CuboidFileError, TemplateInputError, PartMapError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(out)
    save_template(res.template, out / f"{name}.json")
    write_bytes(out / f"{name}.report.txt", (res.report() + "\n").encode())
    if not args.no_png:
        write_template_png(res.template, out / f"{name}.png")
    print(res.report())
    print(f"-> {out / (name + '.json')}")
    return 0
