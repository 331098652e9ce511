"""`make dataset`: build the default procedural dataset, then say where it is and what it holds.

Defaults (8 categories × 16 models × 4 views × 2 variants, 256² renders, 128² sketches) finish
within about ten minutes on 2 cores. Any BuildDataset parameter can be overridden, e.g.
``python -m workflows.make_dataset --models-per-category 4 --categories mug,car``. Progress shows
on one line; Luigi's log goes to ``<work-dir>/luigi.log``; the end is a table per category.
"""

from __future__ import annotations

import argparse
import sys
import time

import luigi

from workflows import steps
from workflows.console import Console
from workflows.tasks import BuildDataset
from workflows.validate import BuildParameterError


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m workflows.make_dataset", description=__doc__)
    p.add_argument("--source", default="procedural")
    p.add_argument("--categories", default="", help="comma-separated (default: all of the source)")
    p.add_argument("--models-per-category", type=int, default=16, help="0 = every model")
    p.add_argument("--views", type=int, default=4)
    p.add_argument("--variants", type=int, default=2)
    p.add_argument("--image-size", type=int, default=256)
    p.add_argument("--out-size", type=int, default=128)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--work-dir", default="data/work")
    p.add_argument("--dataset-dir", default="data/dataset")
    for stage in ("prepare", "render", "augment", "shard"):
        p.add_argument(f"--{stage}-settings", default="", help=f"JSON object of {stage} settings overrides")
    p.add_argument("--verify", action="store_true", help="check every shard's sha256 (default: sizes, "
                                                          "and sha256 of shards edited after the build)")
    p.add_argument("--max-failed-fraction", type=float, default=1.0,
                   help="exit 1 when more than this fraction of a category's models failed")
    a = p.parse_args(argv)
    if a.workers < 1:
        print(f"error: --workers must be >= 1, got {a.workers}", file=sys.stderr)
        return 2
    try:
        task = BuildDataset(source=a.source, categories=a.categories, models_per_category=a.models_per_category,
                            views=a.views, variants=a.variants, image_size=a.image_size, out_size=a.out_size,
                            seed=a.seed, batch_size=a.batch_size, work_dir=a.work_dir, dataset_dir=a.dataset_dir,
                            prepare_settings=a.prepare_settings, render_settings=a.render_settings,
                            augment_settings=a.augment_settings, shard_settings=a.shard_settings,
                            verify=a.verify, max_failed_fraction=a.max_failed_fraction)
    except BuildParameterError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    if a.workers > 1:  # Luigi forks a child per task: load and compile the stages once, here
        from workflows.warm import warm_stage_code

        warm_stage_code()
    console = Console.install()
    console.watch(task)
    ok = luigi.build([task], local_scheduler=True, workers=a.workers)
    clean = console.finish()
    secs = steps.stage_seconds(task.build, task.listings())
    busy = sum(secs.values()) or 1.0
    print("stage time (summed over workers): " + ", ".join(
        f"{k} {v:.0f} s ({100 * v / busy:.0f}%)" for k, v in secs.items()))
    print(f"{'built' if ok and clean else 'FAILED'} in {time.perf_counter() - t0:.0f} s")
    return 0 if ok and clean else 1


if __name__ == "__main__":
    sys.exit(main())
