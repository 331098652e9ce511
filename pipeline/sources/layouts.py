"""Where source meshes come from: procedural shapes, ShapeNet Core v2, or a plain folder tree.

Each layout is one ``Layout`` entry in ``LAYOUTS`` (how to recognise a source of it, list its
categories, and stream its models); ``detect_layout``, ``list_categories`` and ``iter_models``
only look the layout up. A new layout is one ``register_layout(Layout(...))`` call at the end of
this file.

Directory sources are listed by walking directories (names only, in sorted order) and stopping
at ``limit``; no mesh is opened here, so a 13k-model ShapeNet tree lists in well under a second.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Iterator

from pipeline.core.names import is_safe_component, safe_component
from pipeline.core.records import ModelRef
from pipeline.core.schema import sample_key, sidecar_path
from pipeline.core.stage_keys import stage_key
from pipeline.sources.mesh_io import mesh_extensions

# ShapeNet Core v2 synset ids of the paper's 8 categories. "gun" is the rifle synset (the
# largest gun class, and what the procedural guns imitate); pass "03948459" to read pistols.
SHAPENET_SYNSETS = {
    "02691156": "airplane",
    "02808440": "bathtub",
    "02876657": "bottle",
    "02958343": "car",
    "03467517": "guitar",
    "04090263": "gun",
    "03624134": "knife",
    "03797390": "mug",
}
SHAPENET_IDS = {name: synset for synset, name in SHAPENET_SYNSETS.items()}
# Other synsets readable by id (category name = "pistol"), not part of the default 8.
EXTRA_SYNSETS = {"03948459": "pistol"}
SHAPENET_MODEL_FILE = Path("models") / "model_normalized.obj"
_SYNSET_RE = re.compile(r"^\d{8}$")

# Procedural models materialized per category when no limit is given, and the defect share
# the source stage uses (part of its settings key).
DEFAULT_PROCEDURAL_COUNT = 100
DEFECT_FRACTION = 0.25


def _sorted_entries(folder: Path) -> list[os.DirEntry]:
    """Entries of one directory, sorted by name (only names are read, nothing is opened)."""
    with os.scandir(folder) as it:
        return sorted(it, key=lambda e: e.name)


@dataclass(frozen=True)
class Layout:
    """One source layout. ``detect(source)`` says whether a source string is of this layout
    (layouts are tried in registration order, the ``catch_all`` one last); ``categories(source)``
    lists its category names, sorted; ``models(source, category, seed, work_dir, count)`` streams
    a category's ModelRefs in a fixed order (``count``: how many a generating layout makes, None
    for its default; a file layout ignores it). ``also_accepts(source)`` names categories that are
    valid to ask for without being listed (ShapeNet synset ids, pistols)."""

    name: str
    detect: Callable[[str], bool]
    categories: Callable[[str], list[str]]
    models: Callable[[str, str, int, Path | None, int | None], Iterator[ModelRef]]
    also_accepts: Callable[[str], set[str]] = field(default=lambda source: set())
    catch_all: bool = False


LAYOUTS: dict[str, Layout] = {}


def register_layout(layout: Layout) -> Layout:
    """Add a layout (its name must be new); every function of this module then knows it."""
    if layout.name in LAYOUTS:
        raise ValueError(f"source layout {layout.name!r} is already registered")
    LAYOUTS[layout.name] = layout
    return layout


def layout_of(source: str | Path) -> Layout:
    """The registered layout a source is (a directory no other layout claims is a "folder")."""
    ordered = sorted(LAYOUTS.values(), key=lambda lay: lay.catch_all)  # stable: registration order
    for layout in ordered:
        if layout.detect(str(source)):
            return layout
    raise FileNotFoundError(f"source {source!r} is neither 'procedural' nor a directory")


def detect_layout(source: str | Path) -> str:
    """The name of the source's layout: "procedural", "shapenet" (synset-id folders), "folder"
    (<root>/<category>/*.ext) or one registered since."""
    return layout_of(source).name


def list_categories(source: str) -> list[str]:
    """Category names a source offers, sorted (for ShapeNet: those of the 8 synsets present)."""
    return layout_of(source).categories(str(source))


def _subdirs(source: str) -> list[str]:
    return [e.name for e in _sorted_entries(Path(source)) if e.is_dir()]


# Category names become folder names in every stage and in the dataset folder, next to
# manifest.json and the bookkeeping folders ("_runs", "_lists"): none may start with "_" or ".".
CATEGORY_LEADING = "_."


def safe_category(folder_name: str) -> str:
    """The category a source folder is built as: its own name when that is a safe folder name
    (pipeline.core.names), else a slug plus a hash of it (``manifest.json`` → ``manifest_json-…``)."""
    return safe_component(folder_name, leading=CATEGORY_LEADING)


def model_id_of(file_name: str) -> str:
    """A model's id from its file or folder name: the name without its last extension when that
    is a safe file name, else a slug plus a hash of it (a 250-character or unicode name, a
    backslash or braces); the original name stays in the model's source path (meta.json)."""
    return safe_component(Path(file_name).stem)


def _folder_categories(source: str) -> dict[str, str]:
    """{category: folder name} of a folder source (hidden folders skipped); a folder whose safe
    name another folder already has is left out (only names made up to collide do that)."""
    out: dict[str, str] = {}
    for d in _subdirs(source):
        if not d.startswith("."):
            out.setdefault(safe_category(d), d)
    return dict(sorted(out.items()))


def iter_shapenet(root: Path, category: str) -> Iterator[ModelRef]:
    """ShapeNet Core v2 models of one category (name or synset id), in model-id order."""
    known = {**SHAPENET_SYNSETS, **EXTRA_SYNSETS}
    synset = category if category in known else {n: s for s, n in known.items()}.get(category)
    if synset is None:
        raise ValueError(f"unknown ShapeNet category {category!r}; known: {sorted(known.values())}")
    name = known[synset]
    folder = root / synset
    if not folder.is_dir():
        return
    # The path is reported even when the file is missing: prepare records that failure.
    yield from unique_ids(
        ModelRef(name, safe_component(e.name), Path(e.path) / SHAPENET_MODEL_FILE, "shapenet")
        for e in _sorted_entries(folder)
        if e.is_dir() and not e.name.startswith(".")
    )


class ModelIdClash(ValueError):
    """Two source files of one category would become the same sample; the message names both."""


def unique_ids(refs: Iterable[ModelRef]) -> Iterator[ModelRef]:
    """Pass ``refs`` through, raising ModelIdClash at the first two whose sample keys would be equal.

    Keys are compared case-folded too: on a case-insensitive disk (macOS, Windows shares) two
    such models would share one work folder.
    """
    seen: dict[str, ModelRef] = {}
    for ref in refs:
        key = sample_key(ref.category, ref.model_id)
        other = seen.setdefault(key.casefold(), ref)
        if other is not ref:
            raise ModelIdClash(
                f"{ref.category}: {other.path.name!r} and {ref.path.name!r} would both be model "
                f"{key!r} (ids are file names without extension, '.' read as '_'); rename one of them"
            )
        yield ref


def iter_folder(root: Path, category: str) -> Iterator[ModelRef]:
    """Mesh files directly in the folder of ``category`` (``<root>/<category>/``, or the folder
    whose ``safe_category`` it is), id = ``model_id_of(file name)``.

    The id depends on the file's own name only, so adding or removing other files never renames
    a model; two files that would get the same sample key raise ModelIdClash naming both.
    Every entry named like a mesh is listed, even one that is not a readable file (a directory,
    a FIFO, a broken link): prepare then records why it can't be read instead of skipping it.
    """
    name = _folder_categories(str(root)).get(category) if root.is_dir() else None
    if name is None:
        return
    folder = root / name
    extensions = mesh_extensions()
    files = [
        e for e in _sorted_entries(folder) if not e.name.startswith(".") and Path(e.name).suffix.lower() in extensions
    ]
    yield from unique_ids(ModelRef(category, model_id_of(e.name), Path(e.path), "folder") for e in files)


def procedural_source_dir(work_dir: Path, seed: int) -> Path:
    """Folder of the materialized procedural source models for this seed."""
    from pipeline.shapes import SHAPES_VERSION

    key = stage_key("source", {"seed": seed, "defect_fraction": DEFECT_FRACTION, "shapes": SHAPES_VERSION})
    return Path(work_dir) / key


def _write_procedural(model, obj: Path) -> None:
    """Write OBJ + sidecar into a temp folder, then move the OBJ and, last, the sidecar into place:
    the sidecar's presence marks a complete model, so a killed run never leaves a half one."""
    obj.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".{obj.stem}.", dir=obj.parent) as tmp:
        tmp_obj = Path(tmp) / obj.name
        model.write(tmp_obj)
        os.replace(tmp_obj, obj)
        os.replace(sidecar_path(tmp_obj), sidecar_path(obj))


def iter_procedural(category: str, count: int, seed: int, work_dir: Path) -> Iterator[ModelRef]:
    """Generate (once) and yield procedural models 0..count-1 of a category as OBJ + sidecar."""
    from pipeline.shapes import CATEGORIES, generate

    if category not in CATEGORIES:
        raise ValueError(f"unknown procedural category {category!r}; known: {list(CATEGORIES)}")
    folder = procedural_source_dir(work_dir, seed) / category
    for index in range(count):
        model_id = f"{index:05d}"
        obj = folder / f"{model_id}.obj"
        if not (obj.is_file() and sidecar_path(obj).is_file()):
            _write_procedural(generate(category, index, seed=seed, defect_fraction=DEFECT_FRACTION), obj)
        yield ModelRef(category, model_id, obj, "procedural")


def iter_models(
    source: str, category: str, seed: int = 0, work_dir: Path | None = None, count: int | None = None
) -> Iterator[ModelRef]:
    """Stream the models of one category of a source, in deterministic order. Every model id is
    a safe file name (``safe_component``) whatever layout made it: ids name work folders."""
    for ref in layout_of(source).models(str(source), category, seed, work_dir, count):
        safe = ref.model_id if is_safe_component(ref.model_id) else safe_component(ref.model_id)
        yield ref if safe == ref.model_id else dataclasses.replace(ref, model_id=safe)


def list_models(source: str, category: str, limit: int | None, seed: int, work_dir: Path) -> list[ModelRef]:
    """The first ``limit`` models (all if None) of a category, sorted and deterministic."""
    it = iter_models(source, category, seed=seed, work_dir=work_dir, count=limit)
    return list(it if limit is None else itertools.islice(it, limit))


def _procedural_models(
    source: str, category: str, seed: int, work_dir: Path | None, count: int | None
) -> Iterator[ModelRef]:
    if work_dir is None:
        raise ValueError("the procedural source needs a work_dir to write its meshes to")
    return iter_procedural(category, DEFAULT_PROCEDURAL_COUNT if count is None else count, seed, work_dir)


def _procedural_categories(source: str) -> list[str]:
    from pipeline.shapes import CATEGORIES

    return sorted(CATEGORIES)


register_layout(
    Layout(
        "procedural",
        detect=lambda source: source == "procedural",
        categories=_procedural_categories,
        models=_procedural_models,
    )
)
register_layout(
    Layout(
        "shapenet",
        detect=lambda source: Path(source).is_dir() and any(_SYNSET_RE.match(n) for n in _subdirs(source)),
        categories=lambda source: sorted(SHAPENET_SYNSETS[d] for d in _subdirs(source) if d in SHAPENET_SYNSETS),
        models=lambda source, category, seed, work_dir, count: iter_shapenet(Path(source), category),
        also_accepts=lambda source: set(SHAPENET_SYNSETS) | set(EXTRA_SYNSETS) | set(EXTRA_SYNSETS.values()),
    )
)
register_layout(
    Layout(
        "folder",
        detect=lambda source: Path(source).is_dir(),
        categories=lambda source: list(_folder_categories(source)),
        models=lambda source, category, seed, work_dir, count: iter_folder(Path(source), category),
        catch_all=True,
    )
)
