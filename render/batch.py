"""render_batch: render many models in ONE Blender (bpy) subprocess, with a timeout.

Models that already have a record are skipped. A storage or environment error in the worker
(disk full, read-only output, bpy missing: pipeline.core.model_loop) is raised again here, with
no record written. If the worker crashes, is killed or exceeds the batch timeout, every model
still without a record gets a failed record naming the cause and the
tail of the worker's stderr (``on_crash="record"``), or RenderBatchError is raised so a
scheduler can retry the batch (``on_crash="raise"``); finished models keep their records.
"""

from __future__ import annotations

import json
import os
import queue
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from pipeline.core.errors import ModelError
from pipeline.core.records import Progress, model_dir, read_record, write_failed
from render.job import PARENT_ENV, PROGRESS_PREFIX, fatal_from_json, write_job
from render.settings import RenderSettings

PROJECT_ROOT = Path(__file__).resolve().parents[1]
JOB_PREFIX = ".render-job-"


class RenderBatchError(RuntimeError):
    """The worker process died or hung; raised only with on_crash="raise"."""


def worker_command(job_path: Path) -> list[str]:
    return [sys.executable, "-m", "render.worker", str(job_path)]


def render_batch(
    category: str,
    items: list[tuple[str, Path]],
    stage_dir: Path,
    settings: RenderSettings,
    seed: int,
    progress: Progress = None,
    on_crash: str = "record",
) -> list[dict]:
    """Render every (model_id, mesh path) of ``items``; returns their records in order."""
    if on_crash not in ("record", "raise"):
        raise ValueError(f"on_crash must be 'record' or 'raise', got {on_crash!r}")
    # absolute paths: the worker runs with the project root as its working directory
    stage_dir = Path(stage_dir).resolve()
    total = len(items)
    pending = [
        (mid, Path(mesh).resolve()) for mid, mesh in items if read_record(model_dir(stage_dir, category, mid)) is None
    ]
    done0 = total - len(pending)
    if progress is not None:
        progress(done0, total, f"render {category}: {done0} already done")
    if pending:
        _run_worker(category, pending, stage_dir, settings, seed, progress, on_crash, done0, total)
    return [read_record(model_dir(stage_dir, category, mid)) for mid, _ in items]


def _run_worker(
    category: str,
    pending: list[tuple[str, Path]],
    stage_dir: Path,
    settings: RenderSettings,
    seed: int,
    progress: Progress,
    on_crash: str,
    done0: int,
    total: int,
) -> None:
    (stage_dir / category).mkdir(parents=True, exist_ok=True)
    remove_stale_jobs(stage_dir / category)
    work = Path(tempfile.mkdtemp(prefix=f"{JOB_PREFIX}{socket.gethostname()}-{os.getpid()}-", dir=stage_dir / category))
    try:
        job_path = work / "job.json"
        write_job(job_path, category, pending, stage_dir, settings, seed, work / "scratch")
        timeout = settings.batch_timeout_s(len(pending))
        stderr_path = work / "stderr.txt"
        current: list[str] = []  # the model the worker last started
        fatal: list[dict] = []  # a storage or environment error the worker reported
        cause = _supervise(job_path, stderr_path, timeout, progress, done0, total, current, fatal)
        if fatal:
            raise fatal_from_json(fatal[0])  # disk full, bpy missing...: the batch fails, no record
        if cause is None:
            missing = [mid for mid, _ in pending if read_record(model_dir(stage_dir, category, mid)) is None]
            if not missing:
                return
            cause = "render worker exited without rendering every model"
        tail = _tail(stderr_path)
        reason = f"{cause}; stderr tail: {tail}" if tail else cause
        if on_crash == "raise":
            raise RenderBatchError(f"render batch {category}: {reason}")
        culprit = current[-1] if current else None
        for mid, mesh in pending:
            folder = model_dir(stage_dir, category, mid)
            if read_record(folder) is None:
                where = (
                    "while rendering this model"
                    if mid == culprit
                    else f"while rendering model {culprit}"
                    if culprit
                    else "before any model"
                )
                write_failed(folder, ModelError(mesh, f"{where}: {reason}"), category=category, model_id=mid)
        if progress is not None:
            progress(total, total, f"render {category}: worker failed: {cause}")
    finally:
        shutil.rmtree(work, ignore_errors=True)


def remove_stale_jobs(folder: Path) -> list[Path]:
    """Delete job folders left by a killed run: those named for this host and a process that no
    longer exists (other hosts' folders are left alone: their owners may still be rendering)."""
    removed = []
    for job in Path(folder).glob(f"{JOB_PREFIX}*"):
        host, _, rest = job.name[len(JOB_PREFIX) :].rpartition("-")[0].rpartition("-")
        pid = int(rest) if rest.isdigit() else 0
        if host == socket.gethostname() and pid > 0 and not _alive(pid):
            shutil.rmtree(job, ignore_errors=True)
            removed.append(job)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _supervise(
    job_path: Path,
    stderr_path: Path,
    timeout: float,
    progress: Progress,
    done0: int,
    total: int,
    current: list[str],
    fatal: list[dict],
) -> str | None:
    """Run the worker; None if it exited cleanly, else a sentence saying how it died. A fatal
    error the worker reported is appended to ``fatal``."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(PROJECT_ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
    env.setdefault("OMP_NUM_THREADS", "1")
    env[PARENT_ENV] = str(os.getpid())  # the worker ends itself if this process dies
    lines: queue.Queue[str | None] = queue.Queue()
    with open(stderr_path, "wb") as err:
        proc = subprocess.Popen(
            worker_command(job_path),
            stdout=subprocess.PIPE,
            stderr=err,
            stdin=subprocess.DEVNULL,
            cwd=str(PROJECT_ROOT),
            env=env,
            text=True,
            errors="replace",
        )
        reader = threading.Thread(target=_pump, args=(proc.stdout, lines), daemon=True)
        reader.start()
        deadline = time.monotonic() + timeout
        timed_out = False
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                timed_out = True
                proc.kill()
                break
            try:
                line = lines.get(timeout=min(left, 1.0))
            except queue.Empty:
                continue
            if line is None:  # stdout closed: the worker is exiting
                break
            if line.startswith(PROGRESS_PREFIX):
                msg = json.loads(line[len(PROGRESS_PREFIX) :])
                if "fatal" in msg:
                    fatal.append(msg["fatal"])
                    continue
                if msg.get("current"):
                    current.append(msg["current"])
                if progress is not None:
                    progress(done0 + msg["done"], total, msg["message"])
        try:
            rc = proc.wait(timeout=max(1.0, deadline - time.monotonic()) if not timed_out else 30)
        except subprocess.TimeoutExpired:
            proc.kill()
            rc = proc.wait()
            timed_out = True
        reader.join(timeout=5)
    if timed_out:
        return f"render worker timed out after {timeout:.1f} s and was killed"
    if rc < 0:
        name = signal.Signals(-rc).name if -rc in signal.valid_signals() else str(-rc)
        return f"render worker killed by signal {name}"
    if rc != 0:
        return f"render worker exited with code {rc}"
    return None


def _pump(stream, lines: "queue.Queue[str | None]") -> None:
    for line in stream:
        lines.put(line.rstrip("\n"))
    lines.put(None)


def _tail(path: Path, n_chars: int = 800) -> str:
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return ""
    return " | ".join(line for line in text.strip()[-n_chars:].splitlines() if line.strip())
