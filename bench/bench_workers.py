"""Scheduling benchmarks for multi-worker builds.

``--count-tasks``: the number of tasks Luigi's scheduler holds for a ShapeNet-sized build
(8 categories, 12,721 models, or --models-per-category N for every category), counted by walking
the real task classes' ``requires()`` (CategoryShards' batches for the counts given), without
running anything. Luigi degrades past ~100k tasks.

``--throughput``: the same small procedural build run from scratch with ``--workers 1`` and
``--workers 2`` (local scheduler, one Luigi worker process per task), models per minute.

    .venv/bin/python bench/bench_workers.py --count-tasks
    .venv/bin/python bench/bench_workers.py --throughput --repeats 2
"""

from __future__ import annotations

import argparse
import collections
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# ShapeNet Core v2 model counts of the paper's 8 categories (gun = rifle synset): 12,721 in all.
SHAPENET_COUNTS = {
    "airplane": 4045,
    "bathtub": 856,
    "bottle": 498,
    "car": 3514,
    "guitar": 797,
    "gun": 2373,
    "knife": 424,
    "mug": 214,
}


def count_tasks(counts: dict[str, int], batch_size: int) -> collections.Counter:
    """Task families and counts of one BuildDataset over categories with these model counts."""
    import luigi

    from workflows.steps import n_batches
    from workflows.tasks import AugmentBatch, BuildDataset, CategoryShards, SourceList

    root = BuildDataset(
        categories=",".join(counts),
        models_per_category=0,
        batch_size=batch_size,
        work_dir="/nonexistent/work",
        dataset_dir="/nonexistent/ds",
    )
    seen: dict[str, luigi.Task] = {}
    stack = [root]
    while stack:
        task = stack.pop()
        if task.task_id in seen:
            continue
        seen[task.task_id] = task
        if isinstance(task, CategoryShards):  # its batches, for these counts instead of the source's
            stack.extend(
                [task.clone(SourceList)]
                + [task.clone(AugmentBatch, batch=b) for b in range(n_batches(counts[task.category], batch_size))]
            )
        else:
            stack.extend(luigi.task.flatten(task.requires()))
    return collections.Counter(t.task_family for t in seen.values())


def throughput(workers: int, args) -> float:
    """Models per minute of one from-scratch build with ``workers`` Luigi workers."""
    tmp = Path(tempfile.mkdtemp(prefix="bench-workers-"))
    try:
        cmd = [
            str(ROOT / ".venv" / "bin" / "luigi"),
            "--module",
            "workflows",
            "BuildDataset",
            "--local-scheduler",
            "--workers",
            str(workers),
            "--categories",
            args.categories,
            "--models-per-category",
            str(args.models),
            "--batch-size",
            str(args.batch_size),
            "--views",
            str(args.views),
            "--variants",
            "1",
            "--image-size",
            str(args.image_size),
            "--out-size",
            "64",
            "--work-dir",
            str(tmp / "work"),
            "--dataset-dir",
            str(tmp / "ds"),
            "--log-level",
            "WARNING",
        ]
        t0 = time.perf_counter()
        subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True)
        seconds = time.perf_counter() - t0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    n = args.models * len(args.categories.split(","))
    return 60.0 * n / seconds


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--count-tasks", action="store_true")
    p.add_argument("--throughput", action="store_true")
    p.add_argument("--models-per-category", type=int, default=0, help="0 = ShapeNet's real counts")
    p.add_argument("--batch-sizes", default="16,64")
    p.add_argument("--categories", default="knife,mug", help="throughput build")
    p.add_argument("--models", type=int, default=8, help="throughput build: models per category")
    p.add_argument("--batch-size", type=int, default=2, help="throughput build")
    p.add_argument("--views", type=int, default=2)
    p.add_argument("--image-size", type=int, default=128)
    p.add_argument("--repeats", type=int, default=1)
    args = p.parse_args()
    if args.count_tasks:
        counts = (
            SHAPENET_COUNTS if args.models_per_category == 0 else {c: args.models_per_category for c in SHAPENET_COUNTS}
        )
        print(f"{sum(counts.values())} models in {len(counts)} categories")
        for bs in (int(b) for b in args.batch_sizes.split(",")):
            by_family = count_tasks(counts, bs)
            print(
                f"batch_size {bs}: {sum(by_family.values())} tasks "
                + ", ".join(f"{k} {v}" for k, v in sorted(by_family.items()))
            )
        print(f"(one task per model and stage would be {3 * sum(counts.values()) + 3 * len(counts) + 1})")
    if args.throughput:
        print(f"load average before: {os.getloadavg()}")
        for w in (1, 2):
            rates = [throughput(w, args) for _ in range(args.repeats)]
            print(
                f"workers {w}: median {statistics.median(rates):.1f} models/min "
                f"({', '.join(f'{r:.1f}' for r in rates)})"
            )
        print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
