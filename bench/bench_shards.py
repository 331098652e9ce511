"""Shard write (and read-back) throughput on synthetic per-model stage folders.

Each model: 16384 surface points, 4 views × 2 variants of 128² sketches (random line drawings),
strokes.json and cameras.json of realistic size. Prints medians over repeats.
Run: OMP_NUM_THREADS=1 .venv/bin/python bench/bench_shards.py [--models 64] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import webdataset as wds

from pipeline.core.atomic import write_json, write_npy
from pipeline.core.seeding import rng_for
from pipeline.dataset.shards import ModelDirs, ShardSettings, list_shards, write_category_shards


def fake_model(root: Path, category: str, model_id: str, views: int = 4, variants: int = 2) -> ModelDirs:
    rng = rng_for(0, "bench", category, model_id)
    prep, rend, aug = (root / s / category / model_id for s in ("prepare", "render", "augment"))
    pts = rng.normal(size=(16384, 6)).astype(np.float32)
    write_npy(prep / "samples.npy", pts)
    write_json(
        prep / "record.json",
        {
            "status": "ok",
            "source": {"path": f"{model_id}.obj", "sha256": "0" * 64},
            "normalization": {"center": [0, 0, 0], "scale": 1.0},
        },
    )
    write_json(
        rend / "cameras.json",
        {"image_size": 256, "views": [{"projection": rng.normal(size=(3, 4))} for _ in range(views)]},
    )
    write_json(rend / "record.json", {"status": "ok"})
    aug.mkdir(parents=True, exist_ok=True)
    strokes = []
    for v in range(views):
        variants_doc = []
        for k in range(variants):
            img = np.full((128, 128), 255, np.uint8)
            lines = [rng.uniform(0, 128, size=(int(rng.integers(5, 30)), 2)) for _ in range(40)]
            for line in lines:
                cv2.polylines(img, [line.astype(np.int32)], False, int(rng.integers(0, 120)), 1, cv2.LINE_AA)
            cv2.imwrite(str(aug / f"sketch_{v:02d}_{k:02d}.png"), img)
            variants_doc.append({"width": 2.5, "strokes": [np.round(line, 2) for line in lines]})
        strokes.append({"variants": variants_doc})
    write_json(aug / "strokes.json", {"out_size": 128, "views": strokes})
    write_json(aug / "record.json", {"status": "ok"})
    return ModelDirs(model_id, prep, rend, aug)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--models", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        models = [fake_model(root / "work", "mug", f"{i:05d}") for i in range(a.models)]
        st = ShardSettings(max_samples_per_shard=16)
        writes, reads = [], []
        for r in range(a.repeats):
            out = root / f"ds{r}" / "mug"
            t = time.perf_counter()
            write_category_shards("mug", models, out, st, 0, "bench")
            writes.append(time.perf_counter() - t)
            urls = [str(p) for p in list_shards(out)]
            t = time.perf_counter()
            n = sum(1 for _ in wds.WebDataset(urls, shardshuffle=False).decode("l"))
            reads.append(time.perf_counter() - t)
            assert n == a.models
        total = sum(p.stat().st_size for p in list_shards(root / "ds0" / "mug"))
        w, rd = statistics.median(writes), statistics.median(reads)
        print(
            f"models={a.models} shards={len(list_shards(root / 'ds0' / 'mug'))} bytes={total / 2**20:.1f} MiB "
            f"({total / a.models / 1024:.0f} KiB/sample)"
        )
        print(
            f"write (assemble + tar + sha256 + publish): median {w:.3f} s = {a.models / w:.0f} samples/s, "
            f"{total / w / 2**20:.0f} MiB/s"
        )
        print(f"read back with webdataset + decode: median {rd:.3f} s = {a.models / rd:.0f} samples/s")


if __name__ == "__main__":
    main()
