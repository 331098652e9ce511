"""Two worker processes building one dataset through a central scheduler (luigid).

luigid runs on a free port of 127.0.0.1 with its own state file and log folder (and
``[resources] blender = 1``), two ``luigi --module workflows BuildDataset --scheduler-host ...``
processes start at once on the same settings and folders. Every task's run is recorded under
``<work>/_runs/`` (workflows.steps.record_run), which proves each batch ran exactly once, in one of
the two workers, and that no two Blender batches overlapped. The shards must be byte-identical to
a local-scheduler build.
"""

from __future__ import annotations

import os
import socket
import subprocess
import time
from pathlib import Path

import pytest

from pipeline.dataset.shards import list_shards
from workflows.steps import read_runs

ROOT = Path(__file__).resolve().parents[1]
BIN = ROOT / ".venv" / "bin"
SMALL = [
    "--categories",
    "knife,mug",
    "--models-per-category",
    "4",
    "--batch-size",
    "2",
    "--views",
    "1",
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
BATCH_TASKS = ("PrepareBatch", "RenderBatch", "AugmentBatch")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def env_with(**extra: str) -> dict[str, str]:
    return {**os.environ, "OMP_NUM_THREADS": "1", **extra}


@pytest.fixture
def luigid(tmp_path: Path):
    """A central scheduler in the foreground, killed at teardown; yields its port."""
    cfg = tmp_path / "scheduler.cfg"  # read after ./luigi.cfg, so it overrides the blender cap
    cfg.write_text("[resources]\nblender = 1\n")
    port = free_port()
    proc = subprocess.Popen(  # the documented launcher: 127.0.0.1, state in a private folder
        [
            str(BIN / "python"),
            "-m",
            "workflows.scheduler",
            "--port",
            str(port),
            "--state-dir",
            str(tmp_path / "luigid"),
        ],
        cwd=ROOT,
        env=env_with(LUIGI_CONFIG_PATH=str(cfg)),
        stdout=subprocess.DEVNULL,
        stderr=open(tmp_path / "luigid.err", "wb"),
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"luigid did not start: {(tmp_path / 'luigid.err').read_text()[-2000:]}")
                time.sleep(0.2)
        yield port
    finally:
        proc.kill()
        proc.wait(timeout=30)


def dirs(root: Path) -> list[str]:
    return ["--work-dir", str(root / "work"), "--dataset-dir", str(root / "ds")]


@pytest.mark.slow  # a local build plus a two-worker build with Blender (~1 min on 2 cores)
def test_two_workers_share_one_build(luigid: int, tmp_path: Path) -> None:
    luigi = [str(BIN / "luigi"), "--module", "workflows", "BuildDataset"]
    ref = subprocess.run(
        luigi + ["--local-scheduler"] + SMALL + dirs(tmp_path / "local"),
        cwd=ROOT,
        env=env_with(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert ref.returncode == 0, ref.stderr[-3000:]

    shared = tmp_path / "shared"
    # --no-lock: without it Luigi's pid lock turns the second identical command on this machine away
    cmd = (
        luigi
        + [
            "--scheduler-host",
            "127.0.0.1",
            "--scheduler-port",
            str(luigid),
            "--workers",
            "1",
            "--worker-keep-alive",
            "--no-lock",
        ]
        + SMALL
        + dirs(shared)
    )
    workers = [
        subprocess.Popen(cmd, cwd=ROOT, env=env_with(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for _ in range(2)
    ]
    outs = [w.communicate(timeout=600)[0] for w in workers]
    assert [w.returncode for w in workers] == [0, 0], "\n".join(o[-3000:] for o in outs)

    runs = read_runs(shared / "work")
    batch_runs = {t: r for t, r in runs.items() if t.startswith(BATCH_TASKS)}
    # 2 categories x 2 batches x 3 stages, each run exactly once, start to finish, by one process
    assert len(batch_runs) == 12, sorted(runs)
    for task, recs in runs.items():
        assert len(recs) == 1, (task, recs)
        assert [e["event"] for e in recs[0]["events"]] == ["start", "done"], (task, recs)
    pids = {recs[0]["pid"] for recs in runs.values()}
    assert pids == {w.pid for w in workers}  # both workers took part, nothing else ran tasks
    # [resources] blender = 1 on the scheduler: render batches never overlapped in time
    spans = sorted(
        (r[0]["events"][0]["time"], r[0]["events"][1]["time"])
        for t, r in batch_runs.items()
        if t.startswith("RenderBatch")
    )
    assert all(end <= nxt_start for (_, end), (nxt_start, _) in zip(spans, spans[1:])), spans

    for cat in ("knife", "mug"):
        a, b = list_shards(tmp_path / "local" / "ds" / cat), list_shards(shared / "ds" / cat)
        assert a and [p.name for p in a] == [p.name for p in b]
        assert all(x.read_bytes() == y.read_bytes() for x, y in zip(a, b))
    assert (tmp_path / "local" / "ds" / "manifest.json").read_bytes() == (shared / "ds" / "manifest.json").read_bytes()
