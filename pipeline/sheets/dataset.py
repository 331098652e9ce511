"""Contact sheets from a dataset's shards: one PNG per category, one row per model.

Each row shows every sketch of a model (views × variants), read back from the shards exactly as
the trainer sees them, so the sheet checks the shards rather than the intermediate stages.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image

from pipeline.core.images import contact_sheet, save_png
from pipeline.core.schema import SPLITS, sketch_view_variant
from pipeline.dataset.manifest import read_manifest
from pipeline.dataset.shards import iter_shard


def _decode_gray(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as im:
        return np.asarray(im.convert("L"))


def category_sheet(dataset_dir: Path, category: str, entry: dict, max_models: int = 16) -> np.ndarray:
    """Sheet of the first ``max_models`` samples of a category (train, then val, then test)."""
    images: list[np.ndarray] = []
    labels: list[str] = []
    cols = 1
    n = 0
    for split in SPLITS:
        for shard in entry["splits"][split]["shards"]:
            for key, members in iter_shard(Path(dataset_dir) / category / shard["name"]):
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


def write_previews(dataset_dir: Path, out_dir: Path, max_models: int = 16,
                   categories: list[str] | None = None) -> list[Path]:
    """Write ``<out_dir>/<category>.png`` for each category of the manifest; returns the paths."""
    manifest = read_manifest(dataset_dir)
    written = []
    for category, entry in sorted(manifest["categories"].items()):
        if categories and category not in categories:
            continue
        path = Path(out_dir) / f"{category}.png"
        save_png(path, category_sheet(dataset_dir, category, entry, max_models))
        written.append(path)
    return written
