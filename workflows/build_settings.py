"""User-facing build settings → per-stage settings, stage keys and stage folders.

Stage keys chain: source ← (source, seed); prepare ← prepare settings (+ part label settings for
a file source) + source key; render ←
render settings + seed + prepare key; augment ← augment settings + seed + render key; shards ←
shard settings + seed + augment key (+ the fit key when the fit stage is on); fit ← fit
settings + seed + template files + prepare key. Changing the pencil settings therefore changes only the
augment and shard keys: prepared meshes and renders are found again under their old keys.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
from pathlib import Path

from augment.settings import AugmentSettings
from pipeline.core.build_presets import (
    PER_CATEGORY,
    PRESETS,
    NoCategoryPreset,
    UnknownPreset,
    apply_preset,
    category_preset,
)
from pipeline.core.fit_settings import PatchFitSettings
from pipeline.core.settings_io import SettingError, from_dict, parse_json_object, setting
from pipeline.core.stage_keys import settings_dict, settings_hash, stage_key
from pipeline.dataset.shards import ShardSettings
from pipeline.prepare.settings import PrepareSettings
from pipeline.sources.part_names import read_part_map
from pipeline.sources.segmentation import PartLabelSettings
from render.settings import RenderSettings

DEFAULT_WORK_DIR = Path("data/work")
DEFAULT_DATASET_DIR = Path("data/dataset")
PART_LABEL_CHOICES = ("segmentation", "none")


# The fit stage's templates are files of the trainer (its built-in ones, then ./templates/, as
# train.templates.load_template resolves a name): read here as bytes, never imported (the dataset
# side does not import the trainer). Their content keys the fit stage, so an edited template
# re-fits; the fit's record names the template's own sha256 too.
TEMPLATE_DIRS = (Path(__file__).resolve().parents[1] / "train" / "templates" / "data", Path("templates"))


@functools.lru_cache(maxsize=64)
def _file_sha(path: str, mtime_ns: int, size: int) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def template_fingerprints(named: tuple[str, ...]) -> dict[str, str]:
    """sha256 of every template file a fit could load: the built-in and ./templates/ ones, and
    the files ``named`` (CATEGORY=FILE pairs); names that are no file (sphere24) stand for themselves."""
    # keyed by names that do not depend on where the build runs (the key reaches meta.json)
    paths = {
        f"{where}/{p.name}": p for where, d in zip(("builtin", "user"), TEMPLATE_DIRS) for p in sorted(d.glob("*.json"))
    }
    for item in named:
        p = Path(item.partition("=")[2])
        if p.is_file():
            paths[f"file/{p.name}"] = p
    out = {}
    for name, p in sorted(paths.items()):
        st = p.stat()
        out[name] = _file_sha(str(p.resolve()), st.st_mtime_ns, st.st_size)
    return out


def template_snapshot(ref: str, fingerprints: dict[str, str]) -> bytes | None:
    """The bytes of the file a fit's template ``ref`` loads (resolved as
    train.templates.load_template resolves it), read once; None for a template that is no file
    (sphere24). Raises ValueError naming the file when they are not the content
    ``fingerprints`` (``template_fingerprints``, which key the fit stage) hold: it changed since."""
    import hashlib

    if ref in ("sphere24", "sphere54"):  # the trainer's templates built in code (train.templates.BUILTIN)
        return None
    by_name = (
        []
        if "/" in ref
        else [(f"{w}/{ref}.json", d / f"{ref}.json") for w, d in zip(("builtin", "user"), TEMPLATE_DIRS)]
    )
    entry, path = next(((k, p) for k, p in by_name if p.is_file()), (f"file/{Path(ref).name}", Path(ref)))
    if not path.is_file():
        return None  # no such template: the fit records it failed, naming it
    data = path.read_bytes()
    if fingerprints.get(entry) != hashlib.sha256(data).hexdigest():
        raise ValueError(f"{path}: the template changed while the fit stage read it; run the build again")
    return data


@functools.lru_cache(maxsize=16)
def _read_map(path: str, mtime_ns: int, size: int) -> tuple[tuple[str, str | None], ...]:
    return tuple(read_part_map(path).items())


def _part_map(path: str) -> tuple[tuple[str, str | None], ...]:
    """A part map's entries, read again only when the file changes (a build asks for its stage
    keys once per task, thousands of times at ShapeNet scale)."""
    try:
        st = os.stat(path)
    except OSError as exc:
        raise ValueError(f"cannot read the part map {path}: {exc.strerror or exc}") from None
    return _read_map(os.path.abspath(path), st.st_mtime_ns, st.st_size)


def _overrides(cls_name: str, flag: str) -> dataclasses.Field:
    return dataclasses.field(default="", metadata={"flag": flag, "help": f"JSON object of {cls_name} overrides"})


def _one_spelling(direct: dict, overrides: str) -> dict:
    """A stage's settings from the build's own fields and its JSON overrides. A setting with its
    own flag (``--views``) is given there only: in the JSON too it is an error naming both, where
    one of the two used to win silently."""
    extra = parse_json_object(overrides)
    both = sorted(set(direct) & set(extra))
    if both:
        flags = ", ".join(f"--{k.replace('_', '-')}" for k in both)
        raise ValueError(f"{', '.join(map(repr, both))} has its own flag ({flags}): give it there, not in the JSON")
    return {**direct, **extra}


# smallest allowed value of each integer setting
MINIMUMS = {
    "models_per_category": 0,
    "batch_size": 1,
    "views": 1,
    "variants": 1,
    "image_size": 8,
    "out_size": 8,
    "seed": 0,
}


@dataclasses.dataclass(frozen=True)
class BuildSettings:
    """Everything a dataset build depends on. Paths are not part of any hash."""

    # The stage settings a build names directly take their defaults from the stage classes: one
    # default per setting. Flags and Luigi parameters are made from these fields (help: comments).
    source: str = setting("procedural", "'procedural' or a ShapeNet / <root>/<category>/ folder")
    # A named build (pipeline.core.build_presets): fills the settings left at their defaults
    preset: str = setting(
        "",
        "a named build, the data of a category's quality-table row: "
        + ", ".join(PRESETS)
        + f", or {PER_CATEGORY} (each category its own) (flags win)",
    )
    models_per_category: int = setting(16, "models per category (0 = all)")
    views: int = setting(RenderSettings.views, "rendered views per model")
    variants: int = setting(AugmentSettings.variants, "pencil variants per view")
    image_size: int = setting(RenderSettings.image_size, "render size in pixels; sketches are written at out_size")
    out_size: int = setting(AugmentSettings.out_size, "sketch size in pixels")
    seed: int = setting(PrepareSettings.seed, "seeds every stage (sampling, cameras, pencil, splits)")
    # JSON objects of further per-stage settings; the flags keep their historical names
    prepare_overrides: str = _overrides("PrepareSettings", "prepare_settings")
    render_overrides: str = _overrides("RenderSettings", "render_settings")
    augment_overrides: str = _overrides("AugmentSettings", "augment_settings")
    shard_overrides: str = _overrides("ShardSettings", "shard_settings")
    # The fit stage (opt-in): off, no key, manifest or shard byte changes
    fit_patches: bool = setting(False, "fit each category's template to every model; shards gain the fit")
    fit_overrides: str = _overrides("PatchFitSettings", "fit_settings")
    # A file source's part labels (procedural parts come from the generator): read as
    # `python -m train.templates build --source` reads them, so shards match that template.
    part_labels: str = setting("segmentation", "file source: 'segmentation' (OBJ/glTF/PLY groups, .pts/.seg) or 'none'")
    part_map: str = setting(
        "", "file source: YAML/JSON {part name or glob: common name or null}, as templates build --part-map"
    )
    labels_dir: str = setting("", "file source: folder of points/<id>.pts + points_label/<id>.seg (ShapeNet-part)")
    work_dir: Path = setting(DEFAULT_WORK_DIR, "stage outputs, keyed by settings (never part of a hash)")
    dataset_dir: Path = setting(DEFAULT_DATASET_DIR, "shards and manifest.json")
    batch_size: int = dataclasses.field(
        default=16, metadata={"help": "models per batch task", "significant": False}
    )  # scheduling only, never outputs

    def __post_init__(self) -> None:
        if self.preset and self.preset != PER_CATEGORY:  # per category: for_category() resolves
            self._resolve_preset()
        # here, not in the command line's checks, so library callers are refused alike
        for attr, low in MINIMUMS.items():
            value = getattr(self, attr)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                extra = " (0 = every model)" if attr == "models_per_category" else ""
                raise SettingError(f"{attr} must be an integer >= {low}{extra}, got {value!r}", "BuildSettings", attr)

    def _resolve_preset(self) -> None:
        """The preset's values in the fields the caller left at their defaults (and under the
        caller's keys of each settings JSON). Resolving twice gives the same settings, so tasks
        that pass the preset on to the tasks they require agree with them."""
        try:
            values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
            jsons = {k: parse_json_object(values[k]) for k in values if k.endswith("_overrides")}
        except (ValueError, TypeError):
            return  # an unreadable settings JSON: check_settings names it
        defaults = {f.name: f.default for f in dataclasses.fields(self)}
        try:
            resolved = apply_preset(self.preset, {**values, **jsons}, defaults)
        except UnknownPreset as exc:
            raise SettingError(str(exc), "BuildSettings", "preset") from None
        for k, v in resolved.items():
            # frozen: settings are fixed once made, and this is their making
            if k in jsons:
                v = json.dumps(v, sort_keys=True) if v else ""
            object.__setattr__(self, k, v)

    def for_category(self, category: str) -> "BuildSettings":
        """The settings ``category`` is built with: these, or under ``--preset per-category`` these
        with the category's own preset (SettingError naming ``preset`` when it has none)."""
        return _for_category(self, category) if self.preset == PER_CATEGORY else self

    # ---- per-stage settings
    @property
    def limit(self) -> int | None:
        return self.models_per_category if self.models_per_category > 0 else None

    def prepare_settings(self) -> PrepareSettings:
        return from_dict(PrepareSettings, _one_spelling({"seed": self.seed}, self.prepare_overrides))

    def render_settings(self) -> RenderSettings:
        return from_dict(
            RenderSettings, _one_spelling({"views": self.views, "image_size": self.image_size}, self.render_overrides)
        )

    def augment_settings(self) -> AugmentSettings:
        return from_dict(
            AugmentSettings,
            _one_spelling({"variants": self.variants, "out_size": self.out_size}, self.augment_overrides),
        )

    def shard_settings(self) -> ShardSettings:
        return from_dict(ShardSettings, parse_json_object(self.shard_overrides))

    def fit_settings(self) -> PatchFitSettings:
        return from_dict(PatchFitSettings, parse_json_object(self.fit_overrides))

    def part_label_settings(self) -> PartLabelSettings | None:
        """How prepare names a file source's parts; None for the procedural source (its parts
        come from the generator's sidecar). Raises PartMapError (a ValueError) for a bad map
        and ValueError for an unknown ``part_labels``."""
        if self.is_procedural:
            return None
        if self.part_labels not in PART_LABEL_CHOICES:
            raise ValueError(f"must be one of {', '.join(PART_LABEL_CHOICES)}, got {self.part_labels!r}")
        labels_dir = str(Path(self.labels_dir).resolve()) if self.labels_dir else ""
        part_map = _part_map(self.part_map) if self.part_map else ()
        return PartLabelSettings(
            segmentation=self.part_labels == "segmentation", part_map=part_map, labels_dir=labels_dir
        )

    # ---- source
    @property
    def is_procedural(self) -> bool:
        return self.source == "procedural"

    @property
    def source_root(self) -> Path | None:
        return None if self.is_procedural else Path(self.source).resolve()

    def source_id(self) -> str:
        """How the source is named in hashes and the manifest."""
        return "procedural" if self.is_procedural else str(self.source_root)

    # ---- keys and folders
    def source_key(self) -> str:
        if self.is_procedural:
            from pipeline.sources.layouts import procedural_source_dir

            return procedural_source_dir(Path("."), self.seed).name
        return stage_key("source", {"source": self.source_id(), "seed": self.seed})

    def prepare_key(self) -> str:
        parts = self.part_label_settings()
        if parts is None:  # the procedural key as it always was: its outputs are unchanged
            return stage_key("prepare", self.prepare_settings(), self.source_key())
        # a file source's prepare writes part labels: the map's content and the choice key it
        # (a changed map rebuilds); the "parts" entry also retires folders of older code,
        # which wrote no labels, without touching the procedural key
        return stage_key("prepare", {**settings_dict(self.prepare_settings()), "parts": parts.key()}, self.source_key())

    def render_key(self) -> str:
        return stage_key(
            "render", {"render": settings_dict(self.render_settings()), "seed": self.seed}, self.prepare_key()
        )

    def augment_key(self) -> str:
        return stage_key(
            "augment", {"augment": settings_dict(self.augment_settings()), "seed": self.seed}, self.render_key()
        )

    def fit_key(self, templates: dict[str, str] | None = None) -> str:
        """The fit stage's key; ``templates``: the template fingerprints to key it with (read now
        when None), so a step that snapshots a template keys its folder with what it read."""
        fit = self.fit_settings()
        prints = template_fingerprints(fit.templates) if templates is None else templates
        return stage_key("fit", {"fit": settings_dict(fit), "seed": self.seed, "templates": prints}, self.prepare_key())

    def shards_key(self) -> str:
        settings = {"shards": settings_dict(self.shard_settings()), "seed": self.seed}
        if self.fit_patches:  # only then: with the stage off the key is what it always was
            settings["fit"] = self.fit_key()
        return stage_key("shards", settings, self.augment_key())

    def stage_dir(self, stage: str) -> Path:
        key = {
            "source": self.source_key,
            "prepare": self.prepare_key,
            "render": self.render_key,
            "augment": self.augment_key,
            "shards": self.shards_key,
            "fit": self.fit_key,
        }[stage]()
        return Path(self.work_dir) / key

    # ---- what the manifest records
    def manifest_settings(self) -> dict:
        """All settings a category's shards depend on, with no paths of this machine."""
        return {
            "source": "procedural" if self.is_procedural else Path(self.source).name,
            "models_per_category": self.models_per_category,
            "seed": self.seed,
            "prepare": settings_dict(self.prepare_settings()),
            "render": settings_dict(self.render_settings()),
            "augment": settings_dict(self.augment_settings()),
            "shards": settings_dict(self.shard_settings()),
            **({} if self.is_procedural else {"parts": self._parts_manifest()}),
            **({"fit": settings_dict(self.fit_settings())} if self.fit_patches else {}),
            "stage_keys": {s: self.stage_dir(s).name for s in self.stages()},
        }

    def stages(self) -> tuple[str, ...]:
        """The stages this build runs, in order (the fit stage only when asked for)."""
        return ("source", "prepare", "render", "augment") + (("fit",) if self.fit_patches else ()) + ("shards",)

    def _parts_manifest(self) -> dict:
        """The part label settings without this machine's paths (the labels folder by name)."""
        key = self.part_label_settings().key()
        return {**key, "labels_dir": Path(key["labels_dir"]).name if key["labels_dir"] else None}

    def category_settings_hash(self) -> str:
        return settings_hash(self.manifest_settings())

    def portable_path(self, path: str | Path | None) -> str | None:
        """``path`` relative to the work folder or the source root, so manifests and meta.json
        are the same wherever the build ran; other paths are kept as they are."""
        if path is None:
            return None
        p = Path(os.path.abspath(path))
        roots = [Path(os.path.abspath(self.work_dir))]
        if self.source_root is not None:
            roots.append(self.source_root)
        for root in roots:
            try:
                return p.relative_to(root).as_posix()
            except ValueError:
                continue
        return str(path)


@functools.lru_cache(maxsize=64)
def _for_category(s: BuildSettings, category: str) -> BuildSettings:
    # cached: the console and the completeness checks ask once per category and tick
    try:
        return dataclasses.replace(s, preset=category_preset(s.preset, category))
    except NoCategoryPreset as exc:
        raise SettingError(str(exc), "BuildSettings", "preset") from None
