"""workflows.warm: a forking Luigi process compiles the stages' code once, before its children."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_warm_up_compiles_what_the_vectorizer_uses() -> None:
    # In a fresh interpreter: the vectorizer's numba functions are compiled (or loaded from
    # numba's cache) by the warm-up, so a forked task child finds them ready (numba keeps one
    # signature per compiled variant).
    code = (
        "from workflows.warm import warm_stage_code; import augment.skeleton_graph as g; "
        "import augment.vectorize as v; fns = (g._pixel_links, g._walk_all, v._end_offset); "
        "before = sum(len(f.signatures) for f in fns); warm_stage_code(); import gc; "
        "print(before, min(len(f.signatures) for f in fns), gc.get_freeze_count())"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    before, after, frozen = map(int, out.stdout.split())
    assert before == 0 and after >= 1
    assert frozen > 10_000  # what the imports loaded is out of the collector's way
