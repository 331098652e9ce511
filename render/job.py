"""The job file that render.batch hands to the worker process (plain JSON, no bpy)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from pipeline.core.atomic import read_json, write_json
from render.settings import RenderSettings

PROGRESS_PREFIX = "@@render-progress "
PARENT_ENV = "SKETCH_RENDER_PARENT"  # pid of the process that started the worker


def settings_from_dict(d: dict) -> RenderSettings:
    d = dict(d)
    if "elevation_range" in d:
        d["elevation_range"] = tuple(float(x) for x in d["elevation_range"])
    if "edge_types" in d:
        d["edge_types"] = tuple(d["edge_types"])
    return RenderSettings(**d)


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
    job["settings"] = settings_from_dict(job["settings"])
    return job
