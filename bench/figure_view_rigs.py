"""Rows of drawings from two or more builds of the same models side by side: the first view, pencil
variant 0, of the first N models of a split, one row per build, each row labelled.

Usage: .venv/bin/python bench/figure_view_rigs.py --category airplane --out docs/images/airplane_view_rigs.png \
           --build "default rig=data/airplane1000" --build "view_area_fraction 0.6=data/airplane1000_area"
"""

from __future__ import annotations

import argparse
import glob
from pathlib import Path

import cv2
import numpy as np
import webdataset as wds

from pipeline.core.schema import sketch_name


def first_drawings(dataset: Path, category: str, split: str, n: int) -> list[np.ndarray]:
    """View 0, variant 0 of the first ``n`` models of ``split`` (shard order)."""
    urls = sorted(glob.glob(str(dataset / category / f"{split}-*.tar")))
    if not urls:
        raise SystemExit(f"error: {dataset / category}: no {split} shards")
    member = sketch_name(0, 0)
    out = []
    for sample in wds.WebDataset(urls, shardshuffle=False, empty_check=False):
        if member in sample:
            img = cv2.imdecode(np.frombuffer(sample[member], np.uint8), cv2.IMREAD_GRAYSCALE)
            out.append(img)
        if len(out) == n:
            break
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", required=True)
    ap.add_argument("--build", action="append", required=True, help="LABEL=DATASET_DIR (repeat; one row each)")
    ap.add_argument("--split", default="test")
    ap.add_argument("--models", type=int, default=8)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    rows = []
    for item in a.build:
        label, _, path = item.partition("=")
        imgs = first_drawings(Path(path), a.category, a.split, a.models)
        row = np.hstack(imgs)
        band = np.full((22, row.shape[1]), 255, np.uint8)
        cv2.putText(band, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, 0, 1, cv2.LINE_AA)
        rows.append(np.vstack([band, row]))
    width = max(r.shape[1] for r in rows)
    sheet = np.vstack([np.pad(r, ((0, 0), (0, width - r.shape[1])), constant_values=255) for r in rows])
    a.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(a.out), sheet)
    print(f"wrote {a.out} ({len(rows)} rows of {a.models})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
