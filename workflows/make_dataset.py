"""`make dataset`: build the default procedural dataset, then say where it is and what it holds.

Defaults (8 categories × 16 models × 4 views × 2 variants, 256² renders, 128² sketches) finish
within about ten minutes on 2 cores. Any BuildDataset parameter can be overridden, e.g.
``python -m workflows.make_dataset --models-per-category 4 --categories mug,car``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import luigi

from pipeline.manifest import read_manifest
from pipeline.splits import SPLITS
from workflows import steps
from workflows.tasks import BuildDataset


def summary(dataset_dir: Path) -> str:
    """Counts per category and split, failures, and totals, as printed at the end of a build."""
    m = read_manifest(dataset_dir)
    lines = [f"dataset: {Path(dataset_dir).resolve()}",
             f"{'category':<10} {'built':>5} {'failed':>6} " + " ".join(f"{s:>5}" for s in SPLITS) + "  shards"]
    for name, c in sorted(m["categories"].items()):
        shards = sum(len(c["splits"][s]["shards"]) for s in SPLITS)
        lines.append(f"{name:<10} {c['models_built']:>5} {c['models_failed']:>6} "
                     + " ".join(f"{c['splits'][s]['samples']:>5}" for s in SPLITS) + f"  {shards:>6}")
    t = m["totals"]
    lines.append(f"{'total':<10} {t['models_built']:>5} {t['models_failed']:>6} "
                 + " ".join(f"{t[s]:>5}" for s in SPLITS) + f"  {t['shards']:>6}")
    for name, c in sorted(m["categories"].items()):
        for f in c["failed"]:
            lines.append(f"failed {name}/{f['model_id']} at {f['stage']}: {f['reason'][:160]}")
    lines.append(f"manifest: {Path(dataset_dir).resolve() / 'manifest.json'} (checksum {m['checksum'][:16]})")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m workflows.make_dataset", description=__doc__)
    p.add_argument("--source", default="procedural")
    p.add_argument("--categories", default="", help="comma-separated (default: all of the source)")
    p.add_argument("--models-per-category", type=int, default=16)
    p.add_argument("--views", type=int, default=4)
    p.add_argument("--variants", type=int, default=2)
    p.add_argument("--image-size", type=int, default=256)
    p.add_argument("--out-size", type=int, default=128)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--work-dir", default="data/work")
    p.add_argument("--dataset-dir", default="data/dataset")
    a = p.parse_args(argv)
    task = BuildDataset(source=a.source, categories=a.categories, models_per_category=a.models_per_category,
                        views=a.views, variants=a.variants, image_size=a.image_size, out_size=a.out_size,
                        seed=a.seed, batch_size=a.batch_size, work_dir=a.work_dir, dataset_dir=a.dataset_dir)
    t0 = time.perf_counter()
    if a.workers > 1:  # Luigi forks a child per task: load and compile the stages once, here
        from workflows.warm import warm_stage_code

        warm_stage_code()
    ok = luigi.build([task], local_scheduler=True, workers=a.workers, log_level="INFO")
    elapsed = time.perf_counter() - t0
    if not ok or not (Path(a.dataset_dir) / "manifest.json").exists():
        print(f"dataset build FAILED after {elapsed:.0f} s (see the Luigi log above)", file=sys.stderr)
        return 1
    print(summary(Path(a.dataset_dir)))
    secs = steps.stage_seconds(task.build, task.category_list())
    busy = sum(secs.values()) or 1.0
    print("stage time (summed over workers): " + ", ".join(
        f"{k} {v:.0f} s ({100 * v / busy:.0f}%)" for k, v in secs.items()))
    print(f"built in {elapsed:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
