"""CPU seconds per model of one stage, for two checkouts of the code, alternated in one run.

    OMP_NUM_THREADS=1 .venv/bin/python bench/compare_stage.py --work /tmp/bench_pipeline/work \\
        --stage augment --roots /path/to/main /path/to/branch [--every 3] [--rounds 2]

On a shared machine absolute CPU times drift with the load; the ratio of two code versions
measured alternately (A B A B ...) over the same models does not. ``--work`` is the work folder
of a ``bench/bench_pipeline.py`` run (embree backend): the stage is re-run from its inputs there
(prepare: the source meshes; render: the prepared line meshes, all in ONE embree worker, so its
start-up is included once; augment: the rendered views, 8 views x 4 variants) into a temporary
folder, every ``--every``-th model; ``vectorize`` times only the vectorizer, every ``--every``-th
rendered view (any work folder with embree or Freestyle renders; the figure is per view). Each
side runs in a fresh process with its root first on the
path and its imports and numba compilation done before timing (as a long-lived worker would).
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def cpu_seconds() -> float:
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def measure(stage: str, work: Path, every: int) -> dict:
    """Run the stage here (the code on sys.path) and return its CPU seconds per model (per view
    for ``vectorize``)."""
    from workflows.warm import warm_stage_code

    warm_stage_code()
    if stage == "vectorize":
        from augment.batch import load_gray
        from augment.vectorize import vectorize

        views = [load_gray(p) for p in sorted(glob.glob(str(work / "render-*" / "*" / "*" / "view_*.png")))[::every]]
        c = cpu_seconds()
        for gray in views:
            vectorize(gray)
        return {"models": len(views), "cpu_per_model": (cpu_seconds() - c) / max(len(views), 1)}
    key = "augment" if stage == "augment" else "prepare"
    records = sorted(glob.glob(str(work / f"{key}-*" / "*" / "*" / "record.json")))[::every]
    docs = [(Path(r).parent, json.loads(Path(r).read_text())) for r in records]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        if stage == "prepare":
            from pipeline.core.records import ModelRef
            from pipeline.prepare.batch import PrepareSettings, prepare_files

            c = cpu_seconds()
            for folder, rec in docs:
                (out / folder.name).mkdir()
                ref = ModelRef(rec["category"], rec["model_id"], Path(rec["source"]["path"]), "folder")
                prepare_files(ref, out / folder.name, PrepareSettings())
        elif stage == "render":
            from render.batch import render_batch
            from render.settings import RenderSettings

            c = cpu_seconds()
            render_batch(
                "mixed",
                [(folder.name, folder / "lines.ply") for folder, _ in docs],
                out,
                RenderSettings(views=8, backend="embree"),
                0,
            )
        else:
            from augment.batch import augment_model
            from augment.settings import AugmentSettings

            c = cpu_seconds()
            for folder, rec in docs:
                (out / folder.name).mkdir()
                augment_model(
                    rec["category"],
                    rec["model_id"],
                    Path(rec["render_dir"]),
                    out / folder.name,
                    AugmentSettings(variants=4),
                    0,
                )
        return {"models": len(docs), "cpu_per_model": (cpu_seconds() - c) / max(len(docs), 1)}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--stage", choices=("prepare", "render", "augment", "vectorize"), required=True)
    ap.add_argument("--roots", type=Path, nargs=2, metavar=("A", "B"))
    ap.add_argument("--every", type=int, default=1)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--measure-here", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure_here:
        print(json.dumps(measure(args.stage, args.work, args.every)))
        return 0
    unit = "view" if args.stage == "vectorize" else "model"
    figures: dict[str, list[float]] = {str(r): [] for r in args.roots}
    for _ in range(args.rounds):
        for root in args.roots:
            env = dict(os.environ, PYTHONPATH=str(root.resolve()), OMP_NUM_THREADS="1")
            out = subprocess.run(
                [
                    sys.executable,
                    str(Path(__file__).resolve()),
                    "--measure-here",
                    "--stage",
                    args.stage,
                    "--work",
                    str(args.work.resolve()),
                    "--every",
                    str(args.every),
                    "--roots",
                    ".",
                    ".",
                ],
                cwd=root,
                env=env,
                capture_output=True,
                text=True,
                check=True,
            )
            res = json.loads(out.stdout.strip().splitlines()[-1])
            figures[str(root)].append(res["cpu_per_model"])
            print(f"{root}: {res['cpu_per_model']:.4f} core-s per {unit} ({res['models']} {unit}s)", flush=True)
    a, b = (statistics.median(figures[str(r)]) for r in args.roots)
    print(
        f"{args.stage}: median {a:.4f} -> {b:.4f} core-s per {unit} (B/A {b / a:.2f}); load average {os.getloadavg()[0]:.1f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
