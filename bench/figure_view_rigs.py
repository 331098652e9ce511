"""The same models drawn by two or more builds, one row per build: the first view, pencil variant
0, of the first N models of a split, each labelled with its build and model.

Usage: .venv/bin/python bench/figure_view_rigs.py --category airplane --out docs/images/airplane_view_rigs.png \
           --build "default rig=data/airplane1000" --build "view_area_fraction 0.6=data/airplane1000_area"
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.core.images import contact_sheet, save_png  # noqa: E402
from pipeline.core.schema import sketch_name  # noqa: E402
from pipeline.dataset.shards import iter_shard  # noqa: E402


def first_drawings(dataset: Path, category: str, split: str, n: int) -> list[tuple[str, np.ndarray]]:
    """(model key, view 0 in variant 0) of the first ``n`` models of ``split``, in shard order."""
    shards = sorted((dataset / category).glob(f"{split}-*.tar"))
    if not shards:
        raise SystemExit(f"error: {dataset / category}: no {split}-*.tar shards")
    member = sketch_name(0, 0)
    out = []
    for shard in shards:
        for key, members in iter_shard(shard):
            if member in members:
                out.append((key, cv2.imdecode(np.frombuffer(members[member], np.uint8), cv2.IMREAD_GRAYSCALE)))
            if len(out) == n:
                return out
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", required=True)
    ap.add_argument("--build", action="append", required=True, help="LABEL=DATASET_DIR (repeat; one row each)")
    ap.add_argument("--split", default="test")
    ap.add_argument("--models", type=int, default=8)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    images, labels = [], []
    for item in a.build:
        label, _, path = item.partition("=")
        row = first_drawings(Path(path), a.category, a.split, a.models)
        if len(row) < a.models:
            raise SystemExit(
                f"error: {path}: {len(row)} {a.split} models with a {sketch_name(0, 0)}, {a.models} asked for"
            )
        images += [img for _, img in row]
        labels += [f"{label}: {key}" if j == 0 else key for j, (key, _) in enumerate(row)]
    save_png(a.out, contact_sheet(images, labels, cols=a.models))
    print(f"wrote {a.out} ({len(a.build)} rows of {a.models})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
