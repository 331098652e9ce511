"""The job file that render.batch hands to the worker process (plain JSON, no bpy)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from pipeline.core.atomic import read_json, write_json
from pipeline.core.settings_io import from_dict
from render.settings import RenderSettings

PROGRESS_PREFIX = "@@render-progress "
PARENT_ENV = "SKETCH_RENDER_PARENT"  # pid of the process that started the worker


def write_job(path: Path, category: str, items: list[tuple[str, Path]], stage_dir: Path,
              settings: RenderSettings, seed: int, scratch_dir: Path) -> None:
    write_json(path, {
        "category": category,
        "items": [{"model_id": mid, "mesh": str(mesh)} for mid, mesh in items],
        "stage_dir": str(stage_dir),
        "settings": dataclasses.asdict(settings),
        "seed": int(seed),
        "scratch_dir": str(scratch_dir),
    })


def read_job(path: Path) -> dict:
    job = read_json(path)
    job["settings"] = from_dict(RenderSettings, job["settings"])
    return job
