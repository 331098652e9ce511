"""workflows.warm: a forking Luigi process compiles the stages' code once, before its children."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from workflows.warm import forks_per_task

ROOT = Path(__file__).resolve().parents[1]


def test_forks_per_task_reads_the_workers_option() -> None:
    assert forks_per_task(["--module", "workflows", "BuildDataset", "--workers", "2"])
    assert forks_per_task(["BuildDataset", "--workers=4", "--local-scheduler"])
    assert not forks_per_task(["BuildDataset", "--workers", "1"])
    assert not forks_per_task(["BuildDataset", "--local-scheduler"])  # luigi.cfg keeps 1 worker


def test_warm_up_compiles_what_the_vectorizer_uses() -> None:
    # In a fresh interpreter: skan's uncached numba functions are compiled by the warm-up, so a
    # forked task child finds them ready (numba keeps one signature per compiled variant).
    code = ("from workflows.warm import warm_stage_code; import skan.csr as c; "
            "before = len(c._build_paths.signatures); warm_stage_code(); import gc; "
            "print(before, len(c._build_paths.signatures), gc.get_freeze_count())")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    before, after, frozen = map(int, out.stdout.split())
    assert before == 0 and after >= 1
    assert frozen > 10_000  # what the imports loaded is out of the collector's way
