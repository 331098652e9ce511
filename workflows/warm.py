"""Load and JIT-compile the stages' code once in the process that runs Luigi's workers.

With ``--workers N`` (N > 1) Luigi runs every task in a forked child. A child inherits what its
parent has imported and compiled, and loses what it does itself when it exits: without this,
every augment batch re-compiled the vectorizer's numba functions (skan's then: ~3.5 s) and every
batch re-imported its stage (~1–1.5 s), which ate the second worker's gain (measured in
BENCHMARKS.md). With one worker the tasks run in this process, which loads the same code anyway;
the warm-up's ``gc.freeze`` then keeps those imports out of the collector's scans there too.
"""

from __future__ import annotations

import gc


def warm_stage_code() -> None:
    """Import every stage and run the vectorizer and a view's pencil variants once on a tiny
    drawing (compiles their numba functions in this process); then move everything
    loaded so far out of the garbage collector's sight."""
    import cv2
    import numpy as np

    # Luigi's workers are the parallelism; OpenCV's own thread pool (on by default, unlike the
    # OpenMP pools OMP_NUM_THREADS holds to one) only adds CPU: labelling a 256² view took 2.4×
    # the CPU with two threads. Forked task children inherit the setting.
    cv2.setNumThreads(1)
    import pipeline.prepare.batch  # noqa: F401
    import render.batch  # noqa: F401
    from augment.vectorize import vectorize

    img = np.full((48, 48), 255, np.uint8)
    cv2.rectangle(img, (8, 8), (40, 40), 0, 2)
    cv2.line(img, (8, 24), (40, 24), 0, 2)  # a T-junction too: junction code paths compile
    strokes = vectorize(img)
    # a view's pencil variants too: resampling, stroke augmentations, tone strokes and the pencil,
    # all compiled (augment.fitting, augment.strokes, augment.shading, augment.stroke_raster)
    from augment.settings import AugmentSettings
    from augment.variants import view_variants

    view_variants(strokes, 48, AugmentSettings(variants=2, out_size=32), (0, "warm", "warm", 0))
    # and the stroke files' compiled number writer (pipeline.core.points_text)
    from pipeline.core.points_text import points_json

    points_json([np.array([[1.25, -2.0]])], 2)
    # The imports leave ~225k long-lived objects that every full collection would scan again while
    # the stages allocate millions of small ones (stroke points, JSON lists); frozen, they are
    # skipped (augment + shards 0.62 -> 0.56 core-s per model, BENCHMARKS.md). Forked task children
    # inherit the frozen set, and their copy-on-write pages stay shared.
    gc.freeze()
