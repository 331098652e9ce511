"""Contact sheets from a dataset's shards: one PNG per category, one row per model.

Each row shows every sketch of a model (views × variants), read back from the shards exactly as
the trainer sees them, so the sheet checks the shards rather than the intermediate stages.

The manifest is read as untrusted: a category name becomes a file name only through
``safe_component`` (``../../x`` is written as ``x-<hash>.png`` inside ``out_dir``), and a shard
is read only from inside the dataset folder; a category whose shards lie elsewhere is refused.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image

from pipeline.core.images import contact_sheet, save_png
from pipeline.core.names import UnsafePath, inside, safe_component
from pipeline.core.schema import SHARD_RE, SPLITS, sketch_view_variant
from pipeline.dataset.manifest import read_manifest
from pipeline.dataset.shards import iter_shard


def _decode_gray(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as im:
        return np.asarray(im.convert("L"))


def shard_path(dataset_dir: Path, category: str, name: str) -> Path:
    """``<dataset_dir>/<category>/<name>`` for a manifest's shard entry; UnsafePath unless the
    name is a shard file name and the path lies inside the dataset folder."""
    if not isinstance(name, str) or not SHARD_RE.fullmatch(name):
        raise UnsafePath(f"{category!r}: {name!r} is not a shard file name")
    return inside(dataset_dir, Path(dataset_dir) / category / name)


def preview_path(out_dir: Path, category: str) -> Path:
    """Where a category's sheet goes: always a file directly in ``out_dir``."""
    return inside(out_dir, Path(out_dir) / f"{safe_component(category, leading='_.')}.png")


def category_sheet(dataset_dir: Path, category: str, entry: dict, max_models: int = 16) -> np.ndarray:
    """Sheet of the first ``max_models`` samples of a category (train, then val, then test)."""
    images: list[np.ndarray] = []
    labels: list[str] = []
    cols = 1
    n = 0
    for split in SPLITS:
        for shard in entry["splits"][split]["shards"]:
            for key, members in iter_shard(shard_path(dataset_dir, category, shard["name"])):
                if n >= max_models:
                    break
                sketches = sorted(m for m in members if sketch_view_variant(m))
                cols = max(cols, len(sketches))
                for j, name in enumerate(sketches):
                    images.append(_decode_gray(members[name]))
                    view_variant = "{:02d}_{:02d}".format(*sketch_view_variant(name))
                    labels.append(f"{key} [{split}] {view_variant}" if j == 0 else view_variant)
                # pad short rows so every model starts a new row
                while len(images) % cols:
                    images.append(np.full_like(images[-1], 255))
                    labels.append("")
                n += 1
    return contact_sheet(images, labels, cols=cols)


def write_previews(
    dataset_dir: Path,
    out_dir: Path,
    max_models: int = 16,
    categories: list[str] | None = None,
    refused: list[str] | None = None,
) -> list[Path]:
    """Write ``preview_path(out_dir, category)`` for each category of the manifest; returns the
    paths. A category whose shards would be read from outside the dataset folder is skipped,
    with one line on why appended to ``refused`` (raised as UnsafePath when it is None)."""
    manifest = read_manifest(dataset_dir)
    written = []
    for category, entry in sorted(manifest["categories"].items()):
        if categories and category not in categories:
            continue
        try:
            path = preview_path(out_dir, category)
            sheet = category_sheet(dataset_dir, category, entry, max_models)
        except UnsafePath as exc:
            if refused is None:
                raise
            refused.append(f"{category!r} refused: {exc}")
            continue
        save_png(path, sheet)
        written.append(path)
    return written
