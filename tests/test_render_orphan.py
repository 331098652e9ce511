"""kill -9 of the process running a render batch: its Blender worker dies with it, and the job
folder it left is removed by the next run on this host."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import trimesh

from pipeline.sources.mesh_io import write_ply
from render.batch import JOB_PREFIX, remove_stale_jobs

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = """
import sys
from pathlib import Path
from render.batch import render_batch
from render.settings import RenderSettings
mesh, stage = Path(sys.argv[1]), Path(sys.argv[2])
render_batch("mug", [(f"m{i:02d}", mesh) for i in range(40)], stage, RenderSettings(views=8, image_size=64), 0)
"""


def _workers_of(job_dir_parent: Path) -> list[int]:
    """Pids of render workers whose job file lies under ``job_dir_parent``."""
    pids = []
    for proc in Path("/proc").iterdir():
        try:
            cmd = (proc / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"render.worker" in cmd and any(str(job_dir_parent).encode() in c for c in cmd):
            pids.append(int(proc.name))
    return pids


def _wait(predicate, seconds: float) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.2)
    return False


def test_worker_dies_with_killed_parent_and_job_folder_is_cleaned(tmp_path: Path) -> None:
    box = trimesh.creation.box()
    write_ply(tmp_path / "mesh.ply", box.vertices * 0.5, box.faces)
    stage = tmp_path / "render"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    parent = subprocess.Popen(
        [sys.executable, "-c", SCRIPT, str(tmp_path / "mesh.ply"), str(stage)],
        env=env,
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        # the worker has started rendering once the first model's record is written
        assert _wait(lambda: any((stage / "mug").glob("m*/record.json")), 120), "worker never rendered"
        workers = _workers_of(stage)
        assert len(workers) == 1
        jobs = list((stage / "mug").glob(f"{JOB_PREFIX}*"))
        assert len(jobs) == 1
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        assert _wait(lambda: not _workers_of(stage), 10), "render worker outlived its parent"
    finally:
        if parent.poll() is None:
            parent.kill()
        for pid in _workers_of(stage):
            os.kill(pid, signal.SIGKILL)
    assert jobs[0].exists()  # left behind by the kill ...
    other_host = stage / "mug" / f"{JOB_PREFIX}otherhost-1-abc"
    other_host.mkdir()
    assert remove_stale_jobs(stage / "mug") == jobs  # ... and removed by the next run here
    assert not jobs[0].exists() and other_host.exists()  # another machine's job may be running
