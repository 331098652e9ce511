"""What the progress line and Luigi's scheduler cost at ShapeNet's size (issue 34, part 1).

``--tick`` (default): CPU seconds of one tick of the progress line (``StageCounter.counts()``)
for a procedural source of ``--categories`` x ``--models`` (listing only: no mesh is made), in
three states of a build laid out in a scratch work folder: fresh (nothing done), mid-build
(half of prepare's batches finished, a quarter of render's, an eighth of augment's, two batches
running with half their records), and a tick right after a batch finished (its folder
re-listed). Also the first tick (paths derived, everything counted once) and the full recount
``stage_counts`` (one stat per model of an unfinished batch). ``--old FILE`` times the
``stage_counts`` of another console.py as well, e.g. the one before StageCounter:

    git show 4fee696:workflows/console.py > /tmp/console_old.py
    .venv/bin/python bench/bench_console.py --old /tmp/console_old.py

``--schedule``: the whole build's scheduler overhead at that size: ``luigi.build`` of the real
BuildDataset task graph in this process (local scheduler, one worker), with the work of each
stage replaced by a no-op *in this benchmark only*: SourceList writes an empty list file, each
batch step writes its outcome file with every model "failed: no-op", CategoryShards runs the real
shards step (nothing to pack), and the failure threshold is switched off so the root succeeds.
What is left is Luigi (scheduling, complete() checks, events) and the tasks' own code (parameter
checks, outputs, run records). Reports the task count, wall and CPU seconds, per task, and the
re-run of the finished build.

    .venv/bin/python bench/bench_console.py --schedule --schedule-runs 3
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SHAPENET_CATEGORIES = "airplane,bathtub,bottle,car,guitar,gun,knife,mug"


def _root(args, tmp: Path):
    from workflows.tasks import BuildDataset

    return BuildDataset(
        categories=args.categories,
        models_per_category=args.models,
        batch_size=args.batch_size,
        work_dir=str(tmp / "work"),
        dataset_dir=str(tmp / "ds"),
    )


def _cpu(fn, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        out.append(time.process_time() - t0)
    return out


def _fmt(xs: list[float]) -> str:
    return (
        f"median {1000 * statistics.median(xs):.2f} ms CPU "
        f"(min {1000 * min(xs):.2f}, max {1000 * max(xs):.2f}, n={len(xs)})"
    )


def _mid_build(root, listings: list[dict]) -> None:
    """Lay out a build in progress: finished batches' outcome files, two running batches."""
    from pipeline.core.atomic import write_json
    from pipeline.core.records import model_dir, write_ok
    from workflows import steps
    from workflows.tasks import CategoryShards, PrepareBatch

    s = root.build
    for stage, every in (("prepare", 2), ("render", 4), ("augment", 8)):
        for lst in listings:
            for b in range(0, steps.n_batches(len(lst["models"]), s.batch_size), every):
                write_json(steps.batch_path(s, stage, lst, b), {"stage": stage, "models": []})
    for lst in listings[:2]:  # one running prepare batch in each of two categories
        task = root.clone(CategoryShards, category=lst["category"], listing=lst["key"]).clone(PrepareBatch, batch=1)
        steps.record_run(s, task.task_id, "start")
        for m in steps.batch_models(s, lst, 1)[: s.batch_size // 2]:
            write_ok(model_dir(s.stage_dir("prepare"), lst["category"], m["work_id"]))


def tick(args) -> None:
    from workflows import steps
    from workflows.console import StageCounter, batch_task_ids, stage_counts

    tmp = Path(tempfile.mkdtemp(prefix="bench-console-"))
    try:
        root = _root(args, tmp)
        s = root.build
        t0 = time.process_time()
        listings = root.listings()
        n = sum(len(x["models"]) for x in listings)
        print(
            f"{n} models in {len(listings)} categories, batch size {s.batch_size}: "
            f"{sum(steps.n_batches(len(x['models']), s.batch_size) for x in listings)} batches per stage "
            f"(listing {time.process_time() - t0:.2f} s CPU)"
        )
        old = None
        if args.old:
            spec = importlib.util.spec_from_file_location("console_old", args.old)
            old = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(old)
        for state in ("fresh", "mid-build"):
            if state == "mid-build":
                _mid_build(root, listings)
            t0 = time.process_time()
            counter = StageCounter(s, listings, batch_task_ids(root, listings))
            first = counter.counts()
            print(f"{state}: first tick (paths derived, counted once) {time.process_time() - t0:.3f} s CPU; {first}")
            assert first == stage_counts(s, listings), "StageCounter disagrees with the full recount"
            time.sleep(2.1)  # past RACY_S: what a build sees a few seconds after the last change
            print(f"{state}: tick {_fmt(_cpu(counter.counts, args.repeats))}")
            if old is not None:
                before = _cpu(lambda: old.stage_counts(s, listings), args.old_repeats)
                print(f"{state}: old stage_counts ({args.old}) {_fmt(before)}")
        # a tick right after a batch finished: its _batches folder is listed again
        from pipeline.core.atomic import write_json

        lst = max(listings, key=lambda x: len(x["models"]))
        unfinished = range(3, steps.n_batches(len(lst["models"]), s.batch_size), 2)  # batch 1 is running
        todo = iter(unfinished)

        after = []
        for _ in range(min(args.repeats, len(unfinished))):
            write_json(steps.batch_path(s, "prepare", lst, next(todo)), {"stage": "prepare", "models": []})
            after += _cpu(counter.counts, 1)
        if after:
            print(f"tick after a batch of {lst['category']} finished: {_fmt(after)}")
        print(f"full recount stage_counts (mid-build): {_fmt(_cpu(lambda: stage_counts(s, listings), 3))}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _no_op_steps() -> None:
    """Replace the stages' work in this process (only here: the benchmark measures the rest)."""
    from pipeline.core.atomic import write_json
    from workflows import steps, tasks
    from workflows.listing import list_path, procedural_tag

    def write_source_list(s, category):
        write_json(list_path(s, category, procedural_tag(s)), {"category": category, "models": []})
        return 0

    def batch_step(stage):
        def run(s, lst, batch, progress=None, *_):
            outcomes = [
                {
                    "model_id": m["model_id"],
                    "work_id": m["work_id"],
                    "stage": stage,
                    "status": "failed",
                    "error": {"path": m["path"], "reason": "no-op (bench_console.py --schedule)"},
                }
                for m in steps.batch_models(s, lst, batch)
            ]
            return steps._write_batch(s, stage, lst, batch, outcomes, time.perf_counter())

        return run

    steps.write_source_list = write_source_list
    steps.prepare_step, steps.render_step, steps.augment_step = (
        batch_step(x) for x in ("prepare", "render", "augment")
    )
    steps.too_many_failures = lambda *a, **k: []
    assert tasks.steps is steps


def schedule(args) -> None:
    import luigi

    _no_op_steps()
    events: dict[str, list[float]] = {}
    for ev in (luigi.Event.START, luigi.Event.SUCCESS, luigi.Event.DEPENDENCY_PRESENT, luigi.Event.FAILURE):
        luigi.Task.event_handler(ev)(lambda *a, _ev=ev: events.setdefault(_ev, []).append(time.perf_counter()))
    walls, cpus, walks = [], [], []
    for i in range(args.schedule_runs):
        tmp = Path(tempfile.mkdtemp(prefix="bench-schedule-"))
        try:
            for run in ("from scratch", "re-run (all done)"):
                events.clear()
                w0, c0 = time.perf_counter(), time.process_time()
                ok = luigi.build([_root(args, tmp)], local_scheduler=True, workers=1, log_level="WARNING")
                wall, cpu = time.perf_counter() - w0, time.process_time() - c0
                ran = len(events.get(luigi.Event.SUCCESS, []))
                # one in-process worker adds the whole graph (complete() of every task) before it runs any
                walk = events[luigi.Event.START][0] - w0 if events.get(luigi.Event.START) else wall
                present = len(events.get(luigi.Event.DEPENDENCY_PRESENT, []))
                print(
                    f"{i + 1}. {run}: ok={ok}, {ran} tasks ran, {present} "
                    f"found complete, {len(events.get(luigi.Event.FAILURE, []))} failed; wall {wall:.1f} s "
                    f"(graph walk before the first task {walk:.1f} s), CPU {cpu:.1f} s"
                    + (f", {1000 * cpu / ran:.1f} ms CPU per task" if ran else ""),
                    flush=True,
                )
                if ran:
                    walls.append(wall), cpus.append(cpu), walks.append(walk)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    print(
        f"from scratch, median of {len(walls)}: wall {statistics.median(walls):.1f} s, graph walk "
        f"{statistics.median(walks):.1f} s, CPU {statistics.median(cpus):.1f} s"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tick", action="store_true")
    p.add_argument("--schedule", action="store_true")
    p.add_argument("--categories", default=SHAPENET_CATEGORIES)
    p.add_argument("--models", type=int, default=1625, help="per category (8 x 1625 = 13,000)")
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--repeats", type=int, default=50)
    p.add_argument("--old", type=Path, help="a console.py whose stage_counts is timed too")
    p.add_argument("--old-repeats", type=int, default=1)
    p.add_argument("--schedule-runs", type=int, default=1)
    args = p.parse_args()
    if args.schedule:
        sys.path.insert(0, str(ROOT / "bench"))
        from bench_workers import count_tasks

        by_family = count_tasks({c: args.models for c in args.categories.split(",")}, args.batch_size)
        print(f"Luigi tasks: {sum(by_family.values())} ({', '.join(f'{k} {v}' for k, v in sorted(by_family.items()))})")
    if args.tick or not args.schedule:
        tick(args)
    if args.schedule:
        schedule(args)


if __name__ == "__main__":
    main()
