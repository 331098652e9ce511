"""The fit stage's cost per model and its L_Ch per category, on the default procedural set.

Builds the default dataset (`make dataset`'s settings) with `--fit-patches` into its own dataset
folder, sharing `make dataset`'s work folder (prepared meshes, renders and sketches are found
there under their keys; only the fit stage and the shards run when they are current), with one
Luigi worker: the fit's own process runs one thread. Then reads, per category, the fit's figures
from category.json (mean plain L_Ch of the template and of the fits over the models built) and
its cost from the fit batches (CPU seconds of the fitting process, from loading the targets to
the last record; wall seconds of the batch task, which add the process's start and the targets'
gathering).

Usage: OMP_NUM_THREADS=1 .venv/bin/python bench/bench_fit_stage.py
       [--work-dir data/work] [--dataset-dir data/bench_fit] [--fit-settings '{"steps": 150}']
       [--categories knife,mug] [--out bench/results/fit_stage.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import luigi

from pipeline.core.atomic import dumps_json, read_json, write_bytes
from pipeline.core.schema import FRAGMENT_FIT
from pipeline.dataset.manifest import read_fragment
from workflows import BuildDataset
from workflows.steps import batch_path, n_batches


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--work-dir", default="data/work", help="shared with `make dataset` (its stages are reused)")
    p.add_argument("--dataset-dir", default="data/bench_fit", help="not make dataset's: its shards stay as they are")
    p.add_argument("--fit-settings", default="", help="JSON overrides of PatchFitSettings")
    p.add_argument("--categories", default="", help="default: all of the procedural source")
    p.add_argument("--out", default="bench/results/fit_stage.json")
    a = p.parse_args()
    task = BuildDataset(
        work_dir=a.work_dir,
        dataset_dir=a.dataset_dir,
        fit_patches=True,
        fit_settings=a.fit_settings,
        categories=a.categories,
    )
    t0 = time.perf_counter()
    if not luigi.build([task], local_scheduler=True, workers=1, log_level="WARNING"):
        print("build failed; see the Luigi log", file=sys.stderr)
        return 1
    s = task.build
    rows = []
    for lst in task.listings():
        cat = lst["category"]
        docs = [read_json(batch_path(s, "fit", lst, b)) for b in range(n_batches(len(lst["models"]), s.batch_size))]
        fitted = sum(m["status"] == "ok" and m["stage"] == "fit" for d in docs for m in d["models"])
        fit = read_fragment(Path(a.dataset_dir) / cat)[FRAGMENT_FIT]
        cpu = sum(d["cpu_seconds"] for d in docs)
        wall = sum(d["seconds"] for d in docs)
        rows.append(
            {
                "category": cat,
                "template": fit.get("template"),
                "models": fit["models"],
                "fitted": fitted,
                "chamfer_template": fit.get("chamfer_template"),
                "chamfer_fitted": fit.get("chamfer_fitted"),
                "vs_template": fit["chamfer_fitted"] / fit["chamfer_template"] - 1 if fit["models"] else None,
                "cpu_s_per_model": round(cpu / max(fitted, 1), 2),
                "wall_s_per_model": round(wall / max(fitted, 1), 2),
            }
        )
    res = {"settings": s.manifest_settings()["fit"], "seconds": round(time.perf_counter() - t0, 1), "rows": rows}
    print("| category | models | template L_Ch | fitted L_Ch | vs template | CPU s / model | wall s / model |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        if not r["models"]:
            print(f"| {r['category']} | 0 | - | - | - | - | - |")
            continue
        print(
            f"| {r['category']} | {r['models']} | {r['chamfer_template']:.4f} | {r['chamfer_fitted']:.4f} | "
            f"{100 * r['vs_template']:+.0f} % | {r['cpu_s_per_model']:.2f} | {r['wall_s_per_model']:.2f} |"
        )
    print(json.dumps(res["settings"]), f"{res['seconds']} s")
    write_bytes(a.out, dumps_json(res).encode())
    return 0


if __name__ == "__main__":
    sys.exit(main())
