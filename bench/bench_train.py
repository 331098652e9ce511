"""Training throughput on CPU: median seconds per step of `train.fit` on fixture shards.

Usage: OMP_NUM_THREADS=1 .venv/bin/python bench/bench_train.py [--steps 12] [--batch-size 8] [--image-size 128]
       [--template sphere24] [--max-views 4] [--points 7000] [--threads 1] [--collision]
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import tempfile
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from fixtures_shards import write_fixture_shards  # noqa: E402

from train.fit import FitSettings, fit  # noqa: E402
from train.losses.weights import LossWeights  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=12)
    ap.add_argument("--batch-size", type=int, default=8)
    ap.add_argument("--image-size", type=int, default=128)
    ap.add_argument("--template", default="sphere24")
    ap.add_argument("--max-views", type=int, default=4)
    ap.add_argument("--points", type=int, default=7000)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--collision", action="store_true", help="include the collision term (slow on CPU)")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    with tempfile.TemporaryDirectory() as tmp:
        ds = write_fixture_shards(Path(tmp) / "ds", counts={"train": 16, "val": 2, "test": 2}, size=a.image_size)
        w = LossWeights() if a.collision else LossWeights(collision=0.0)
        s = FitSettings(
            dataset=str(ds),
            category="knife",
            template=a.template,
            out=str(Path(tmp) / "run"),
            steps=a.steps,
            batch_size=a.batch_size,
            workers=0,
            image_size=a.image_size,
            log_every=1,
            max_views=a.max_views,
            n_points=a.points,
            weights=w,
        )
        fit(s, progress=False)
        rows = list(csv.DictReader(open(Path(tmp) / "run" / "log.csv")))
    secs = [float(r["seconds"]) for r in rows]
    per_step = [b - a for a, b in zip(secs[1:], secs[2:])]  # skip the first (warm-up) step
    med = statistics.median(per_step)
    print(
        f"template={a.template} batch={a.batch_size} image={a.image_size} views<={a.max_views} "
        f"points={a.points} threads={a.threads} collision={a.collision}: "
        f"median {med:.3f} s/step ({1 / med:.2f} steps/s) over {len(per_step)} steps"
    )


if __name__ == "__main__":
    main()
