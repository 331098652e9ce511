"""The job file that render.batch hands to the worker process (plain JSON, no bpy)."""

from __future__ import annotations

import builtins
import dataclasses
from pathlib import Path

from pipeline.core.atomic import StorageError, read_json, write_json
from pipeline.core.model_loop import FATAL_ERRORS
from pipeline.core.settings_io import from_dict
from render.settings import RenderSettings

PROGRESS_PREFIX = "@@render-progress "
PARENT_ENV = "SKETCH_RENDER_PARENT"  # pid of the process that started the worker
FATAL_EXIT = 3  # the worker's exit code after a ``{"fatal": ...}`` progress line


def write_job(
    path: Path,
    category: str,
    items: list[tuple[str, Path]],
    stage_dir: Path,
    settings: RenderSettings,
    seed: int,
    scratch_dir: Path,
) -> None:
    write_json(
        path,
        {
            "category": category,
            "items": [{"model_id": mid, "mesh": str(mesh)} for mid, mesh in items],
            "stage_dir": str(stage_dir),
            "settings": dataclasses.asdict(settings),
            "seed": int(seed),
            "scratch_dir": str(scratch_dir),
        },
    )


def read_job(path: Path) -> dict:
    job = read_json(path)
    job["settings"] = from_dict(RenderSettings, job["settings"])
    return job


def fatal_to_json(exc: BaseException) -> dict:
    """A storage or environment error of the worker, for the parent to raise again (fatal_from_json)."""
    return {
        "type": type(exc).__name__,
        "errno": getattr(exc, "errno", None),
        "strerror": getattr(exc, "strerror", None),
        "filename": getattr(exc, "filename", None),
        "message": str(exc),
    }


def fatal_from_json(d: dict) -> BaseException:
    """The worker's error as the same kind of exception (StorageError, OSError, MemoryError...)."""
    name, message = str(d.get("type")), str(d.get("message"))
    if d.get("errno") is not None:
        cls = StorageError if name == "StorageError" else OSError  # OSError picks its errno's subclass
        err = cls(int(d["errno"]), d.get("strerror") or message)
        err.filename = d.get("filename")
        return err
    cls = getattr(builtins, name, None)
    if isinstance(cls, type) and issubclass(cls, FATAL_ERRORS):
        return cls(message)
    return RuntimeError(f"render worker: {name}: {message}")
