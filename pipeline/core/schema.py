"""Every name and field the stages and the trainer agree on, in one place.

Writers and readers both import these names; nothing else spells a file name, a shard member, a
``meta.json`` field or a split. Renaming one here renames it everywhere (and changes the bytes of
the dataset, so only with a new dataset format).

Procedural source: each ``<id>.obj`` has a sidecar ``sidecar_path(obj)`` with its part labels.

Per-model stage folders, ``<stage-dir>/<category>/<model_id>/``:

- every stage: ``RECORD`` (written last; see :mod:`pipeline.core.records`);
- prepare: ``MESH_FILE`` (watertight, normalized), ``LINE_MESH_FILE`` (the source surface the
  render stage draws), ``SAMPLES_FILE`` (float32 ``(N, 6)`` surface points + normals) and, for
  a file source with a segmentation, ``SAMPLE_PARTS_FILE`` (uint8 ``(N,)`` per sample, an index
  into the record's ``part_labels["names"]``);
- render: ``view_name(i)`` drawings, ``CAMERAS_FILE``, ``STROKES_FILE`` (captured strokes);
- augment: ``sketch_name(view, variant)`` sketches, ``STROKES_FILE`` (the variants' strokes).

Dataset folder: ``MANIFEST``, and per category ``<category>/FRAGMENT`` and
``<category>/shard_name(split, i)`` WebDataset tars. A shard sample is keyed ``sample_key(...)``;
its members are ``REQUIRED_MEMBERS``, one ``sketch_name(view, variant)`` per view and variant, and
``POINT_PARTS_MEMBER`` where the source has part labels, and ``FIT_MEMBERS`` when the build ran
the fit stage (``<stage-dir>/<category>/<model_id>/FIT_PARAMS_FILE`` + a record of
``FIT_FIELDS``). ``meta.json`` holds the fields of :class:`SampleMeta`.

Part fields. A model's parts come from the procedural generator's sidecar (labels such as
``wing_l``, ``engine0_r``) or, for a file source, from the mesh's segmentation (OBJ groups, glTF
nodes, PLY labels, ShapeNet-part points; :mod:`pipeline.sources.segmentation`). Both the shard
writer and the trainer speak of part *families*: the label without its side and instance
suffixes, which is also what template patches are labelled with. A file source's family is its
part's name normalized and mapped as ``train.templates`` names the parts it builds a template
from (the prepare record's ``parts[i]["family"]``), so shard labels match that template.

- ``meta.json[PRESENT_PARTS]``: sorted families the model has, or None when the source has no
  part labels (then every template part counts as present).
- ``POINT_PARTS_MEMBER``: uint8 ``(N,)`` per surface point of ``POINTS_MEMBER``, an index into
  ``meta.json[POINT_PART_NAMES]`` (the same sorted families); absent without part labels.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any

# ---------------------------------------------------------------- procedural source


def sidecar_path(obj_path: Path) -> Path:
    """The procedural generator's sidecar of an OBJ (part labels, cuboids, defects): same stem, .json."""
    return obj_path.with_suffix(".json")


# ---------------------------------------------------------------- per-model stage folders

RECORD = "record.json"
MESH_FILE = "mesh.ply"
LINE_MESH_FILE = "lines.ply"
SAMPLES_FILE = "samples.npy"
SAMPLE_PARTS_FILE = "sample_parts.npy"
CAMERAS_FILE = "cameras.json"
FIT_PARAMS_FILE = "fit_params.npy"  # the fit stage's per-model result (float32 (D,))
# The fit stage's batch job, handed to its own process (train.patch_fit) and answered there.
FIT_JOB_FILE = "fit_job.json"
# the template file as the fit stage's key saw it, in the job folder: what the fit process loads
FIT_TEMPLATE_FILE = "template.json"
FIT_TARGETS_FILE = "fit_targets.npz"
FIT_RESULT_FILE = "fit_result.json"
STROKES_FILE = "strokes.json"
VIEW_GLOB = "view_*.png"
SKETCH_GLOB = "sketch_*_*.png"
_VIEW_RE = re.compile(r"view_(\d+)\.png")
_SKETCH_RE = re.compile(r"sketch_(\d+)_(\d+)\.png")


def view_name(view: int) -> str:
    """A rendered drawing of the render stage."""
    return f"view_{view:02d}.png"


def view_index(name: str) -> int | None:
    """The view of a ``view_name`` file name, None for any other name."""
    m = _VIEW_RE.fullmatch(name)
    return int(m.group(1)) if m else None


def sketch_name(view: int, variant: int) -> str:
    """A pencil sketch of the augment stage; also its shard member name."""
    return f"sketch_{view:02d}_{variant:02d}.png"


def sketch_view_variant(name: str) -> tuple[int, int] | None:
    """(view, variant) of a ``sketch_name``, None for any other name."""
    m = _SKETCH_RE.fullmatch(name)
    return (int(m.group(1)), int(m.group(2))) if m else None


# ---------------------------------------------------------------- dataset folder and shards

SPLITS = ("train", "val", "test")
MANIFEST = "manifest.json"
FRAGMENT = "category.json"
SHARD_RE = re.compile(rf"^({'|'.join(SPLITS)})-(\d{{5}})\.tar$")

POINTS_MEMBER = "points.npy"  # float32 (N, 6): the prepared surface samples, subsampled
STROKES_MEMBER = STROKES_FILE  # the augment stage's strokes.json
CAMERAS_MEMBER = CAMERAS_FILE  # the render stage's cameras.json
META_MEMBER = "meta.json"  # SampleMeta
POINT_PARTS_MEMBER = "point_parts.npy"
REQUIRED_MEMBERS = (POINTS_MEMBER, STROKES_MEMBER, CAMERAS_MEMBER, META_MEMBER)
# With the fit stage on (BuildSettings.fit_patches): the template fitted to the model.
FIT_PARAMS_MEMBER = FIT_PARAMS_FILE  # float32 (D,): the template's parameters after the fit
FIT_MEMBER = "fit.json"  # FIT_FIELDS: which template, its active patches, L_Ch before and after
FIT_MEMBERS = (FIT_PARAMS_MEMBER, FIT_MEMBER)


def shard_name(split: str, index: int) -> str:
    return f"{split}-{index:05d}.tar"


def shard_glob(split: str) -> str:
    return f"{split}-*.tar"


def sample_key(category: str, model_id: str) -> str:
    """WebDataset key; dots would split the key from the extension, so they become '_'."""
    return f"{category}_{model_id}".replace(".", "_")


# ---------------------------------------------------------------- meta.json

PRESENT_PARTS = "present_parts"
POINT_PART_NAMES = "point_part_names"


@dataclasses.dataclass(frozen=True)
class SampleMeta:
    """``meta.json`` of a shard sample. The writer fills every field (None where the source has
    no such data); readers look fields up by these names."""

    key: str  # sample_key(category, model_id)
    category: str
    model_id: str
    source: str | None  # source mesh path, relative to where the build ran
    source_sha256: str | None
    normalization: dict[str, Any] | None  # {"center": [x, y, z], "scale": s}: source -> unit sphere
    part_labels: list[str] | None  # the generator's part labels, None without a sidecar
    present_parts: list[str] | None  # PRESENT_PARTS
    point_part_names: list[str] | None  # POINT_PART_NAMES, the index of POINT_PARTS_MEMBER
    bodies: int | None  # separate volumes of the prepared mesh (None: older record)
    seed: int
    settings_hash: str
    split: str  # one of SPLITS
    sketches: list[str]  # the sketch members, sorted
    points: int  # rows of POINTS_MEMBER

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


META_FIELDS = tuple(f.name for f in dataclasses.fields(SampleMeta))

# ---------------------------------------------------------------- manifest

# Top-level manifest.json, a category's category.json (also the manifest's entry for it), a
# split of a category, and one shard. "listing" appears only for file sources.
MANIFEST_FIELDS = ("format", "project_version", "settings", "settings_hash", "categories", "totals", "checksum")
FRAGMENT_FIELDS = (
    "category",
    "settings",
    "settings_hash",
    "models_requested",
    "models_built",
    "models_failed",
    "failed",
    "splits",
    "listing",
    "checksum",
)
SPLIT_FIELDS = ("samples", "shards")
SHARD_FIELDS = ("name", "samples", "bytes", "sha256", "keys")
FAILED_FIELDS = ("model_id", "stage", "path", "reason")
# FIT_MEMBER of a sample, also the fit stage's record fields; a category fitted has FRAGMENT_FIT
# in its category.json (the stage's figures over the models built).
FIT_FIELDS = (
    "template",
    "template_sha256",
    "patches",
    "active_patches",
    "steps",
    "lr",
    "points",
    "chamfer_template",
    "chamfer_fitted",
)
FRAGMENT_FIT = "patch_fit"


# ---------------------------------------------------------------- part families


def part_family(label: str) -> str:
    """``wing_l`` → ``wing``, ``engine0_r`` → ``engine``, ``foot_front_l`` → ``foot_front``."""
    return re.sub(r"\d+$", "", re.sub(r"_(l|r|left|right)$", "", label))


def present_parts(labels: list[str] | None) -> list[str] | None:
    """Sorted distinct families of a model's part labels (None when it has none)."""
    return sorted({part_family(x) for x in labels}) if labels else None
