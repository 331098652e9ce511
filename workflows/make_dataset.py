"""`make dataset`: build the default procedural dataset, then say where it is and what it holds.

Defaults (8 categories × 16 models × 4 views × 2 variants, 256² renders, 128² sketches) finish
within about ten minutes on 2 cores. Every BuildDataset parameter is a flag here too, e.g.
``python -m workflows.make_dataset --models-per-category 4 --categories mug,car``. Progress shows
on one line; Luigi's log goes to ``<work-dir>/luigi.log``; the end is a table per category.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import luigi

from pipeline.core.settings_io import add_arguments, from_dict, setting
from workflows import steps
from workflows.console import Console
from workflows.params import add_task_arguments
from workflows.tasks import BuildDataset
from workflows.validate import BuildParameterError
from workflows.warm import warm_stage_code


@dataclasses.dataclass(frozen=True)
class RunSettings:
    """What runs the build, beside what it builds (BuildDataset's parameters)."""

    workers: int = setting(2, "Luigi worker processes")

    def __post_init__(self) -> None:
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m workflows.make_dataset", description=__doc__)
    add_task_arguments(p, BuildDataset)  # the flags of `luigi ... BuildDataset`, made from its parameters
    add_arguments(p, RunSettings)
    a = vars(p.parse_args(argv))
    try:
        workers = from_dict(RunSettings, {"workers": a.pop("workers")}).workers
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        task = BuildDataset(**a)
    except BuildParameterError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    warm_stage_code()  # once here, whether Luigi runs the tasks here or in forked children
    console = Console.install()
    console.watch(task)
    ok = luigi.build([task], local_scheduler=True, workers=workers)
    clean = console.finish()
    secs = steps.stage_seconds(task.build, task.listings())
    busy = sum(secs.values()) or 1.0
    print(
        "stage time (summed over workers): "
        + ", ".join(f"{k} {v:.0f} s ({100 * v / busy:.0f}%)" for k, v in secs.items())
    )
    print(f"{'built' if ok and clean else 'FAILED'} in {time.perf_counter() - t0:.0f} s")
    return 0 if ok and clean else 1


if __name__ == "__main__":
    sys.exit(main())
