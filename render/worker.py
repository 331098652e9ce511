"""Render worker: ``python -m render.worker JOB.json`` renders a whole batch in one process (bpy
for the Freestyle backend, none for the embree backend, render.edge_lines).

For every model of the job still without a record: load its mesh, render every view of its rig,
write view_XX.png (8-bit grayscale, black lines on white), cameras.json, strokes.json and
record.json last (pipeline.core.model_loop). A model that can't be loaded or rendered gets a
failed record; the process goes on with the next one. A storage or environment error (disk full,
bpy missing) ends the process with FATAL_EXIT after a ``fatal`` line, which render_batch raises
again. Progress goes to stdout as ``PROGRESS_PREFIX + json`` lines.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Iterator

import numpy as np
from PIL import Image

from pipeline.core.atomic import write_bytes, write_json
from pipeline.core.errors import ModelError
from pipeline.core.images import encode_png
from pipeline.core.model_loop import FATAL_ERRORS, ModelJob, run_models
from pipeline.core.schema import CAMERAS_FILE, STROKES_FILE, view_name
from pipeline.core.stage_keys import settings_hash
from pipeline.sources.mesh_io import read_ply
from render import cameras
from render.job import FATAL_EXIT, PARENT_ENV, PROGRESS_PREFIX, fatal_to_json, read_job
from render.settings import RenderSettings


def load_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n,3) float64 and triangles (m,3) int64 of a mesh file, or ModelError.

    The prepare stage's PLY is read with numpy alone (``read_ply``), so the embree backend's
    worker never imports trimesh; any other file goes through trimesh."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(path, "mesh file not found")
    try:
        vertices, faces = read_ply(path)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise ModelError(path, f"cannot read mesh: {type(exc).__name__}: {exc}") from None
    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    if len(vertices) == 0 or len(faces) == 0 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ModelError(path, f"no triangles in mesh ({len(vertices)} vertices, {len(faces)} faces)")
    if not np.isfinite(vertices).all():
        raise ModelError(path, "mesh has non-finite vertex coordinates")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ModelError(path, "mesh has face indices out of range")
    return vertices, faces


def grayscale_on_white(rgba: np.ndarray) -> np.ndarray:
    """Composite a straight-alpha RGBA render onto white; 8-bit gray."""
    rgba = rgba.astype(np.int32)
    a = rgba[..., 3]
    lum = (rgba[..., 0] * 299 + rgba[..., 1] * 587 + rgba[..., 2] * 114 + 500) // 1000
    return ((lum * a + 255 * (255 - a) + 127) // 255).astype(np.uint8)


@contextlib.contextmanager
def thread_pool_limited(threads: int) -> Iterator[None]:
    """Start Blender with ``threads`` CPUs visible, then give the process all of them back.

    Blender sizes its TBB pool from the CPU affinity mask when bpy is imported; with every core
    visible its idle workers spin and cost ~40% extra CPU per view even with render threads = 1.
    Restoring the mask afterwards lets the OS still move the worker to any free core.
    """
    if threads <= 0 or not hasattr(os, "sched_setaffinity"):
        yield
        return
    allowed = os.sched_getaffinity(0)
    os.sched_setaffinity(0, sorted(allowed)[:threads])
    try:
        yield
    finally:
        os.sched_setaffinity(0, allowed)


def emit(done: int, total: int, message: str, current: str | None = None) -> None:
    """One progress line; ``current`` names the model being rendered (so a crash can be pinned on it)."""
    line = {"done": done, "total": total, "message": message, "current": current}
    sys.stdout.write(PROGRESS_PREFIX + json.dumps(line) + "\n")
    sys.stdout.flush()


def emit_fatal(exc: BaseException) -> None:
    """Tell render_batch the batch failed for a storage or environment reason (see render.job)."""
    sys.stdout.write(PROGRESS_PREFIX + json.dumps({"fatal": fatal_to_json(exc)}) + "\n")
    sys.stdout.flush()


def _freestyle_view(
    scene, recorder, view: cameras.View, settings: RenderSettings, tmp_png: Path
) -> tuple[np.ndarray, list[dict]]:
    """Render one view with Freestyle: the drawing (uint8 gray) and the strokes it captured."""
    from render import scene as sc

    sc.set_camera(scene, view)
    recorder.reset(settings.image_size, settings.join_gap_px)
    sc.render_png(scene, tmp_png)
    with Image.open(tmp_png) as im:
        rgba = np.asarray(im.convert("RGBA"))
    tmp_png.unlink()
    return grayscale_on_white(rgba), list(recorder.strokes)


def render_model(
    scene,
    recorder,
    category: str,
    model_id: str,
    mesh_path: Path,
    out: Path,
    settings: RenderSettings,
    seed: int,
    scratch: Path,
) -> dict:
    """Draw every view of one model into ``out``; returns its record fields (the loop writes
    record.json). ``scene`` and ``recorder`` are None with the embree backend."""
    t0 = time.perf_counter()
    vertices, faces = load_mesh(mesh_path)
    if scene is None:  # the "embree" backend: no Blender scene
        from render.edge_lines import MeshLines

        lines = MeshLines(vertices, faces, settings)
    else:
        from render import scene as sc

        sc.set_mesh(
            scene,
            vertices,
            faces,
            smooth_below_deg=180.0 - settings.crease_angle_deg if settings.smooth_shading else None,
        )
    t_load = time.perf_counter() - t0
    views = cameras.rig(settings, seed, category, model_id, vertices)
    strokes_per_view, view_times, view_cpu = [], [], []
    for i, view in enumerate(views):
        t, c = time.perf_counter(), time.process_time()
        if scene is None:
            gray, strokes = lines.draw(view)
        else:
            # a fixed name: Blender reads '#', '{…}' and '\\' in an output path, and the
            # folder holds one model's views at a time
            gray, strokes = _freestyle_view(scene, recorder, view, settings, scratch / view_name(i))
        write_bytes(out / view_name(i), encode_png(gray))
        strokes_per_view.append(strokes)
        view_times.append(round(time.perf_counter() - t, 4))
        view_cpu.append(round(time.process_time() - c, 4))
    write_json(out / CAMERAS_FILE, {"image_size": settings.image_size, "views": [v.to_json() for v in views]})
    write_json(out / STROKES_FILE, {"image_size": settings.image_size, "views": strokes_per_view}, compact=True)
    return dict(
        category=category,
        model_id=model_id,
        mesh={"path": str(mesh_path), "n_vertices": int(len(vertices)), "n_faces": int(len(faces))},
        seed=int(seed),
        settings_hash=settings_hash(settings),
        n_views=len(views),
        n_strokes=[len(s) for s in strokes_per_view],
        timings={"load_s": round(t_load, 4), "views_s": view_times, "views_cpu_s": view_cpu},
    )


# Characters Blender replaces in an output path: '#' (frame number), '{…}' (path templates),
# '\\' (read as a folder separator).
BLENDER_PATH_SPECIAL = "#{}\\"


@contextlib.contextmanager
def blender_scratch(preferred: Path) -> Iterator[Path]:
    """The folder Blender renders into: ``preferred`` when its path has none of
    BLENDER_PATH_SPECIAL (the work folder's name is the user's), else a private temporary
    folder, removed afterwards."""
    if not any(c in str(preferred.resolve()) for c in BLENDER_PATH_SPECIAL):
        preferred.mkdir(parents=True, exist_ok=True)
        yield preferred
        return
    tmp = Path(tempfile.mkdtemp(prefix="sketch2patch-render-"))
    if any(c in str(tmp) for c in BLENDER_PATH_SPECIAL):
        tmp.rmdir()
        # the machine's setup, not a model's: fatal for the batch (an OSError), with the reason
        raise NotADirectoryError(
            f"no folder Blender can render into: {preferred} and {tmp} both hold one of {BLENDER_PATH_SPECIAL!r}"
        )
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def run_job(job_path: Path) -> int:
    job = read_job(job_path)
    with blender_scratch(Path(job["scratch_dir"])) as scratch:
        return _run_job(job, scratch)


def _run_job(job: dict, scratch: Path) -> int:
    t0 = time.perf_counter()
    settings: RenderSettings = job["settings"]
    category, seed = job["category"], job["seed"]
    stage_dir = Path(job["stage_dir"])

    scene = recorder = None
    if settings.backend == "freestyle":
        import trimesh  # noqa: F401  (imported here so its ~1 s counts as start-up, not model time)

        with thread_pool_limited(settings.threads):
            from render import scene as sc
            from render.capture import StrokeRecorder

            scene = sc.build_scene(settings)
        recorder = StrokeRecorder()
        recorder.install()
        ready = "blender ready"
    else:
        import render.edge_lines  # noqa: F401  (start-up, not model time)

        ready = f"{settings.backend} backend ready"
    items = job["items"]
    emit(
        0,
        len(items),
        f"{ready} in {time.perf_counter() - t0:.2f}s ({time.process_time():.2f}s CPU since process start)",
    )

    def one(mj: ModelJob, out: Path) -> dict:
        out.mkdir(parents=True, exist_ok=True)
        return render_model(scene, recorder, category, mj.model_id, mj.path, out, settings, seed, scratch)

    jobs = [ModelJob(category, item["model_id"], Path(item["mesh"])) for item in items]
    run_models(
        "render",
        stage_dir,
        jobs,
        one,
        emit,
        on_start=lambda k, mj: emit(k, len(items), f"{mj.model_id} rendering", current=mj.model_id),
        error_prefix="render error: ",
    )
    return 0


def die_with_parent() -> None:
    """End this worker when the process that started it dies (kill -9 included), so no orphan
    keeps rendering into the work folder: Linux's PR_SET_PDEATHSIG, else a watchdog thread."""
    expected = int(os.environ.get(PARENT_ENV, "0")) or os.getppid()
    try:
        import ctypes
        import signal

        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(1, signal.SIGKILL, 0, 0, 0) != 0:  # 1 = PR_SET_PDEATHSIG
            raise OSError(ctypes.get_errno(), "prctl")
    except (OSError, AttributeError):
        import threading

        def watch() -> None:
            while os.getppid() == expected:
                time.sleep(1.0)
            os._exit(1)

        threading.Thread(target=watch, daemon=True).start()
    if os.getppid() != expected:  # the parent died before the line above took effect
        os._exit(1)


def main(argv: list[str] | None = None) -> int:
    die_with_parent()
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m render.worker JOB.json", file=sys.stderr)
        return 2
    try:
        return run_job(Path(argv[0]))
    except FATAL_ERRORS as exc:  # the machine's fault: render_batch re-raises it, records nothing
        traceback.print_exc()
        emit_fatal(exc)
        return FATAL_EXIT


if __name__ == "__main__":
    sys.exit(main())
