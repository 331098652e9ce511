"""A build SIGKILLed at any moment and restarted ends byte-identical to an uninterrupted one.

The kill is deterministic: ``SKETCH_FAULT_KILL_AT="<glob>:<n>"`` makes pipeline.core.atomic SIGKILL the
whole process group (Luigi and its Blender worker) just before the n-th rename onto a matching
path, so the temp file is left behind as after a power cut.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LUIGI = [str(ROOT / ".venv" / "bin" / "luigi"), "--module", "workflows", "BuildDataset", "--local-scheduler"]
SMALL = [
    "--categories",
    "mug",
    "--models-per-category",
    "4",
    "--batch-size",
    "2",
    "--views",
    "2",
    "--variants",
    "1",
    "--image-size",
    "64",
    "--out-size",
    "64",
    "--shard-settings",
    '{"max_samples_per_shard": 2}',
    "--log-level",
    "WARNING",
]

# (where, glob of the path whose n-th atomic rename is interrupted, n)
KILL_POINTS = [
    ("prepare", "*/prepare-*/samples.npy", 3),  # batch 0 done, batch 1 half prepared
    ("render", "*/render-*/view_01.png", 2),  # inside the Blender worker, 2nd model of a batch
    ("augment", "*/augment-*/record.json", 3),
    ("shards", "*/ds/mug/category.json", 1),  # shards moved into place, fragment not yet written
    ("manifest", "*/ds/manifest.json", 1),
]


def run_build(root: Path, kill_at: str | None = None, timeout: float = 300) -> int:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    env.pop("SKETCH_FAULT_KILL_AT", None)
    if kill_at:
        env["SKETCH_FAULT_KILL_AT"] = kill_at
    cmd = LUIGI + SMALL + ["--work-dir", str(root / "work"), "--dataset-dir", str(root / "ds")]
    # own session: the kill hook takes down this process group and nothing else
    proc = subprocess.run(
        cmd, cwd=ROOT, env=env, start_new_session=True, capture_output=True, text=True, timeout=timeout
    )
    if proc.returncode not in (0, -signal.SIGKILL):
        raise AssertionError(f"build exited {proc.returncode}:\n{proc.stderr[-3000:]}")
    return proc.returncode


def visible_files(ds: Path) -> dict[str, str]:
    """sha256 of every file a reader could take (temp files and staging folders start with '.')."""
    out = {}
    for p in sorted(ds.rglob("*")):
        rel = p.relative_to(ds)
        if p.is_file() and not any(part.startswith(".") for part in rel.parts):
            out[rel.as_posix()] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def temp_files(root: Path) -> list[Path]:
    return [p for p in root.rglob(".*") if ".tmp" in p.name]


def assert_done_markers_whole(work: Path) -> None:
    """Every record.json and batch file that exists parses, and an ok record's files exist."""
    for rec_path in work.rglob("record.json"):
        rec = json.loads(rec_path.read_text())
        if rec["status"] == "ok":
            for name in (rec.get("files") or {}).values():
                assert (rec_path.parent / name).is_file(), rec_path
    for batch in work.rglob("_batches/*.json"):
        json.loads(batch.read_text())


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict[str, str]:
    root = tmp_path_factory.mktemp("uninterrupted")
    assert run_build(root) == 0
    files = visible_files(root / "ds")
    assert "manifest.json" in files and any(n.endswith(".tar") for n in files)
    return files


@pytest.mark.slow  # each case: a killed build plus its restart (~20-40 s on 2 cores)
@pytest.mark.parametrize("where,pattern,nth", KILL_POINTS, ids=[k[0] for k in KILL_POINTS])
def test_killed_build_restarts_to_identical_output(
    reference, tmp_path: Path, where: str, pattern: str, nth: int
) -> None:
    assert run_build(tmp_path, f"{pattern}:{nth}") == -signal.SIGKILL
    left = temp_files(tmp_path)
    assert any(p.name.startswith(".") and Path(pattern).name in p.name for p in left), left
    assert not (tmp_path / "ds" / "manifest.json").exists()  # the killed build never finished
    assert_done_markers_whole(tmp_path / "work")
    assert run_build(tmp_path) == 0
    assert visible_files(tmp_path / "ds") == reference
