"""Load and JIT-compile the stages' code once in a Luigi process that forks a child per task.

With ``--workers N`` (N > 1) Luigi runs every task in a forked child. A child inherits what its
parent has imported and compiled, and loses what it does itself when it exits: without this,
every augment batch re-compiled the vectorizer's numba functions (skan's then: ~3.5 s) and every batch re-imported its
stage (~1–1.5 s), which ate the second worker's gain (measured in BENCHMARKS.md).
"""

from __future__ import annotations

import gc
import re
from typing import Sequence


def forks_per_task(argv: Sequence[str]) -> bool:
    """Whether this Luigi command line runs tasks in forked children (``--workers`` > 1, on the
    command line or in luigi.cfg's ``[core]`` section)."""
    text = " ".join(argv)
    m = re.search(r"--workers[= ](\d+)", text)
    if m is None:
        import luigi.configuration

        n = luigi.configuration.get_config().getint("core", "workers", 1)
    else:
        n = int(m.group(1))
    return n > 1


def warm_stage_code() -> None:
    """Import every stage and run the vectorizer and the pencil once on a tiny drawing (compiles
    the skeleton paths' and the pencil's numba functions in this process); then move everything loaded so far
    out of the garbage collector's sight."""
    import cv2
    import numpy as np

    import pipeline.prepare.batch  # noqa: F401
    import render.batch  # noqa: F401
    from augment.vectorize import vectorize

    img = np.full((48, 48), 255, np.uint8)
    cv2.rectangle(img, (8, 8), (40, 40), 0, 2)
    cv2.line(img, (8, 24), (40, 24), 0, 2)  # a T-junction too: junction code paths compile
    vectorize(img)
    # the pencil's compiled steps too (augment.stroke_raster)
    from augment.pencil import draw_pencil

    draw_pencil([np.array([[4.0, 4.0], [20.0, 12.0]]), np.array([[8.0, 30.0]])], 32, 1.0, np.random.default_rng(0))
    # The imports leave ~225k long-lived objects that every full collection would scan again while
    # the stages allocate millions of small ones (stroke points, JSON lists); frozen, they are
    # skipped (augment + shards 0.62 -> 0.56 core-s per model, BENCHMARKS.md). Forked task children
    # inherit the frozen set, and their copy-on-write pages stay shared.
    gc.freeze()
