"""Luigi tasks (`luigi --module workflows BuildDataset --local-scheduler`)."""
import os

# Keep thread pools small: CI machines have 2 cores and tests run Blender subprocesses too.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

from workflows.tasks import (  # noqa: E402  (the environment must be set before numpy loads)
    AugmentBatch,
    BuildCategory,
    BuildDataset,
    CategoryShards,
    PrepareBatch,
    RenderBatch,
    SourceList,
)

__all__ = ["AugmentBatch", "BuildCategory", "BuildDataset", "CategoryShards", "PrepareBatch",
           "RenderBatch", "SourceList"]
