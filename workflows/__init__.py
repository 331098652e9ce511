"""Luigi tasks (`luigi --module workflows BuildDataset --local-scheduler`)."""

import os
import sys

# Keep thread pools small: CI machines have 2 cores and tests run Blender subprocesses too.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

from workflows.tasks import (  # noqa: E402  (the environment must be set before numpy loads)
    AugmentBatch,
    BuildCategory,
    BuildDataset,
    CategoryShards,
    FitBatch,
    PrepareBatch,
    RenderBatch,
    SourceList,
)

# the `luigi` command (or `python -m luigi`), not an importing test or trainer
if "luigi" in os.path.basename(sys.argv[0]) or sys.argv[0].endswith(os.path.join("luigi", "__main__.py")):
    from workflows.console import Console
    from workflows.warm import warm_stage_code

    Console.install()  # progress line, luigi.log in the work folder, summary at exit
    warm_stage_code()

__all__ = [
    "AugmentBatch",
    "BuildCategory",
    "BuildDataset",
    "CategoryShards",
    "FitBatch",
    "PrepareBatch",
    "RenderBatch",
    "SourceList",
]
