"""``python -m train.templates`` commands: their settings (the flags are made from these fields)
and the runs of ``build`` (procedural categories, a folder source, a cuboid file)."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

from pipeline.core.settings_io import setting
from pipeline.shapes import CATEGORIES
from train.templates.authoring.budget import PAPER_PATCHES, SHIPPED_PATCHES
from train.templates.authoring.from_cuboids import TemplateSettings
from train.templates.authoring.symmetry import MIRROR_TOL

USER_DIR = Path("templates")  # relative to where the command runs: never the installed package
SYMMETRIES = ("auto", "x", "none")


class CommandError(ValueError):
    """A flag or a combination of flags the command cannot run with."""


@dataclasses.dataclass(frozen=True)
class TemplatesBuildSettings:
    """``build``: category templates + PNGs from procedural categories, a folder source or a cuboid file."""

    categories: tuple[str, ...] = setting(
        (),
        "built-in procedural categories (default: all eight, when neither --source nor --cuboids is given)",
        choices=CATEGORIES,
    )
    n_models: int = setting(16, "models per category for the median")
    seed: int = setting(0, "seeds the procedural models and the sweep")
    snap_tol: float = setting(TemplateSettings.snap_tol, "lattice snapping (normalized units)")
    out: Path | None = setting(None, f"output folder for <name>.json/.png (default: ./{USER_DIR}/)")
    shipped: bool = setting(False, "write into the package's shipped templates (train/templates/data/)")
    png: bool = setting(True, "write the PNG renders")
    budget: str | None = setting(
        None,
        "max patches: procedural categories 'shipped' (default: the paper's counts, airplane 84), 'paper', "
        "N, cat=N,..., or 'none'; --source/--cuboids: N or 'none' (default) "
        "(coarser lattice, small parts dropped, part labels merged; closest to the median wins)",
    )
    # your own category
    source: str | None = setting(None, "a folder source (DIR/NAME/*.obj ..., or ShapeNet) whose category NAME to build")
    category: str | None = setting(
        None,
        "the category (folder) in --source; the template's name (--cuboids: default the file's "
        "'category', else its file name)",
    )
    cuboids: Path | None = setting(None, "a cuboid file (YAML/JSON, see docs/templates.md)")
    limit: int | None = setting(None, "--source: read at most this many models")
    part_map: Path | None = setting(None, "YAML/JSON {name or glob: common name or null} renaming parts across models")
    labels_dir: Path | None = setting(None, "folder with points/<id>.pts + points_label/<id>.seg (ShapeNet-part)")
    components: bool = setting(False, "ignore segmentations: one part per connected component")
    min_part_size: float | None = setting(
        None, "drop components whose largest extent is under this fraction of the model's size (default 0.04)"
    )
    max_parts: int | None = setting(None, "boxes kept per model, largest first (default 32)")
    presence_threshold: float = setting(
        1.0,
        "a part in at least this share of the models is required, in fewer optional "
        "(1: every part some model lacks is optional)",
    )
    min_presence: float = setting(0.0, "parts in fewer models than this share are dropped")
    symmetry: str | None = setting(
        None, "mirror plane x = 0: auto (default: when the median's boxes pair up), x (force), none", choices=SYMMETRIES
    )
    mirror_tol: float = setting(MIRROR_TOL, "how far (normalized units) mirror boxes may differ")
    hollow: tuple[str, ...] = setting(
        (), "LABEL[=WALL,BOTTOM] ...: build these parts as a floor + four walls open at +y (a cup, a tub)"
    )
    part_group: tuple[str, ...] = setting(
        (), "NAME=LABEL,LABEL ...: labels whose Chamfer/normal terms are computed apart (the paper's car wheels)"
    )
    strict: bool = setting(False, "--source: stop at the first unusable model instead of skipping it")

    def __post_init__(self) -> None:
        unknown = set(self.categories) - set(CATEGORIES)
        if unknown:
            raise CommandError(f"unknown categories {sorted(unknown)}: the built-in ones are {', '.join(CATEGORIES)}")
        if self.symmetry not in (None, *SYMMETRIES):
            raise CommandError(f"symmetry must be one of {SYMMETRIES}, got {self.symmetry!r}")
        if self.n_models < 1:
            raise CommandError(f"n_models must be >= 1, got {self.n_models}")
        hollow_parts(self.hollow)
        part_groups(self.part_group)

    @property
    def user_input(self) -> bool:
        return self.source is not None or self.cuboids is not None

    def out_dir(self) -> Path:
        """Where the templates go; the combinations that cannot run are refused here."""
        from train.templates.authoring.build import DATA_DIR

        if self.shipped and self.out is not None:
            raise CommandError("--shipped and --out both name the output folder: give one")
        if self.user_input:
            if self.categories:
                raise CommandError("--categories (procedural) cannot be combined with --source or --cuboids")
            if self.shipped:
                raise CommandError(
                    "--shipped is for the built-in categories; your templates go to --out (default ./templates/)"
                )
        elif self.category is not None:
            raise CommandError(
                "--category names a category of --source (or a --cuboids template); procedural ones: --categories"
            )
        return DATA_DIR if self.shipped else self.out if self.out is not None else USER_DIR


@dataclasses.dataclass(frozen=True)
class TemplatesSizesSettings:
    """``sizes``: patch count vs Chamfer to the median model, per category."""

    categories: tuple[str, ...] = setting(CATEGORIES, "the categories measured", choices=CATEGORIES)
    n_models: int = setting(16, "models per category for the median")
    seed: int = setting(0, "seeds the procedural models and the sweep")


@dataclasses.dataclass(frozen=True)
class TemplatesRenderSettings:
    """``render``: a template to PNG, one colour per patch."""

    template: tuple[str, ...] = setting(
        help="sphere24, sphere54, a category name, or a template .json path; several are rendered side by side "
        "(e.g. an old and a new template)",
        positional=True,
    )
    out: Path = setting(help="PNG to write")
    size: int = setting(384, "pixels per view (two views side by side)")


def hollow_parts(items: tuple[str, ...]) -> dict[str, tuple[float, float]]:
    """``LABEL`` or ``LABEL=WALL,BOTTOM`` (fractions, as the built-in mug: 0.12,0.12) per item."""
    out = {}
    for text in items:
        label, _, fr = text.partition("=")
        try:
            wall, bottom = (float(x) for x in fr.split(",")) if fr else (0.12, 0.12)
        except ValueError:
            raise CommandError(f"--hollow {text}: use LABEL or LABEL=WALL,BOTTOM") from None
        out[label.strip()] = (wall, bottom)
    return out


def part_groups(items: tuple[str, ...]) -> dict[str, list[str]]:
    """``NAME=LABEL,LABEL,...`` per item."""
    out = {}
    for text in items:
        name, _, labels = text.partition("=")
        if not labels:
            raise CommandError(f"--part-group {text}: use NAME=LABEL,LABEL,...")
        out[name.strip()] = [x.strip() for x in labels.split(",") if x.strip()]
    return out


def category_budget(text: str | None, categories: list[str]) -> dict[str, int] | None:
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
        raise CommandError(f"--budget {text}: use paper, a number, or category=N,...") from None


def run_procedural_build(s: TemplatesBuildSettings, out: Path) -> int:
    from train.templates.authoring.build import BuildSettings, build_all

    categories = list(s.categories) or list(CATEGORIES)
    settings = BuildSettings(
        n_models=s.n_models,
        seed=s.seed,
        template=TemplateSettings(snap_tol=s.snap_tol),
        budget=category_budget(s.budget or "shipped", categories),
    )
    for cat, res in build_all(categories, out, settings, png=s.png).items():
        t = res.template
        print(
            f"{cat}: {t.num_patches} patches, {t.num_params} parameters, median model {res.chosen}, "
            f"Chamfer to it {t.metadata['chamfer_to_median']:.4f}, optional {t.part_names} -> {out / (cat + '.json')}"
        )
    return 0


def run_user_build(args: TemplatesBuildSettings, out: Path) -> int:
    from pipeline.core.atomic import write_bytes
    from pipeline.sources.part_names import PartMapError, read_part_map
    from train.templates.authoring.build import write_template_png
    from train.templates.authoring.cuboid_file import CuboidFileError, file_models, read_cuboid_file
    from train.templates.authoring.mesh_boxes import PartSettings, source_models
    from train.templates.authoring.user import TemplateInputError, UserSettings, build_user_template
    from train.templates.template import save_template

    if (args.source is None) == (args.cuboids is None):
        raise CommandError("give --source DIR --category NAME, or --cuboids FILE (not both)")
    budget = None
    if args.budget not in (None, "none"):
        if not str(args.budget).isdigit():
            raise CommandError(f"--budget {args.budget}: with --source/--cuboids use a number or 'none'")
        budget = int(args.budget)
    try:
        hollow, groups = hollow_parts(args.hollow), part_groups(args.part_group)
        symmetry, skipped = args.symmetry or "auto", {}
        if args.cuboids is not None:
            cf = read_cuboid_file(args.cuboids)
            name = args.category or cf.category or args.cuboids.stem
            models = file_models(cf, seed=args.seed)
            hollow, groups = {**cf.hollow, **hollow}, {**cf.part_groups, **groups}
            symmetry = args.symmetry or cf.symmetry
        else:
            if not args.category:
                raise CommandError("--source needs --category NAME (a folder of the source)")
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
    if args.png:
        write_template_png(res.template, out / f"{name}.png")
    print(res.report())
    print(f"-> {out / (name + '.json')}")
    return 0
