"""Shared vocabulary between stages: a model reference and the per-model record convention.

Every stage writes, per model, a folder ``<stage-dir>/<category>/<model_id>/`` whose
``record.json`` is written last (atomically). Its existence marks the model as done for that
stage, successfully (``status == "ok"``) or not (``status == "failed"`` with ``error``), so a
restarted batch skips it either way and a killed run never leaves a model that looks done.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable, Optional

from pipeline.core.atomic import read_json, write_json
from pipeline.core.errors import ModelError
from pipeline.core.schema import RECORD

# progress(done, total, message): how batch functions report progress to Luigi or a terminal.
Progress = Optional[Callable[[int, int, str], None]]


@dataclasses.dataclass(frozen=True)
class ModelRef:
    """One source model: where its mesh file is and what it is called."""

    category: str
    model_id: str
    path: Path
    source: str  # "procedural", "shapenet" or "folder"


def model_dir(stage_dir: Path, category: str, model_id: str) -> Path:
    return Path(stage_dir) / category / model_id


def read_record(folder: Path) -> dict | None:
    """The model's record if the stage finished it (ok or failed), else None."""
    path = Path(folder) / RECORD
    if not path.exists():
        return None
    return read_json(path)


def write_ok(folder: Path, **fields) -> dict:
    rec = {"status": "ok", **fields}
    write_json(Path(folder) / RECORD, rec)
    return rec


def write_failed(folder: Path, error: ModelError, **fields) -> dict:
    rec = {"status": "failed", "error": error.to_json(), **fields}
    write_json(Path(folder) / RECORD, rec)
    return rec
