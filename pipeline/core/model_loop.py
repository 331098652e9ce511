"""The per-model loop every stage runs (prepare, render, augment), with one error policy.

For each model still without a ``record.json`` in its stage folder the loop calls the stage's
function, which writes the model's files and returns its record fields; the loop then writes the
record, last and atomically, so a killed or failed run never leaves a model that looks done.
Models with a record (ok or failed) are skipped, so a restarted batch resumes.

The policy, in one place:

- **Bad model** → recorded ``failed`` with the file and reason, and the loop goes on: a
  ModelError (what readers and checks raise for bad input), or any other exception on one
  model (a library bug on odd input must not sink the batch; its type is kept in the reason).
- **Storage or environment error** → re-raised, no record written, so the task fails loudly
  and a re-run after the fix builds the model: ``OSError`` (disk full, read-only or
  non-writable output, I/O error: pipeline.core.atomic names the file), ``MemoryError``,
  ``ImportError`` (Blender/bpy or a library missing), and ``KeyboardInterrupt``/``SystemExit``.
  Readers of a model's *input* translate its OSErrors into ModelError themselves (an unreadable
  source mesh is a bad model), so an OSError that reaches the loop is the machine's.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from pipeline.core.errors import ModelError
from pipeline.core.records import Progress, model_dir, read_record, write_failed, write_ok

__all__ = ["FATAL_ERRORS", "ModelJob", "is_fatal", "run_models"]

# What fails the task instead of a model (BaseExceptions that are not Exceptions, such as
# KeyboardInterrupt, are never caught at all).
FATAL_ERRORS: tuple[type[BaseException], ...] = (OSError, MemoryError, ImportError)


def is_fatal(exc: BaseException) -> bool:
    """True if ``exc`` is the machine's fault (fail the task), False if the model's (record it)."""
    return not isinstance(exc, Exception) or isinstance(exc, FATAL_ERRORS)


@dataclasses.dataclass(frozen=True)
class ModelJob:
    """One model for a stage: its name, the input an unexpected error is blamed on, the stage's
    own description of it (``item``: a ModelRef, a mesh path...) and extra fields a failed
    record carries (e.g. prepare's ``source``)."""

    category: str
    model_id: str
    path: Path
    item: Any = None
    failed_fields: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{self.category}/{self.model_id}"


def run_models(
    stage: str,
    stage_dir: Path,
    jobs: Sequence[ModelJob],
    one: Callable[[ModelJob, Path], dict],
    progress: Progress = None,
    on_start: Callable[[int, ModelJob], None] | None = None,
    error_prefix: str = "",
) -> list[dict]:
    """Run ``one(job, folder)`` for every job without a record; returns all records in order.

    ``one`` writes the model's files into ``folder`` and returns the record fields (the loop
    writes ``record.json``). ``progress(done, total, message)`` is called after every model,
    skipped ones included; ``on_start(index, job)`` just before a model is run.
    ``error_prefix`` starts the reason of an unexpected (non-ModelError) failure.
    """
    records = []
    total = len(jobs)
    for i, job in enumerate(jobs):
        folder = model_dir(Path(stage_dir), job.category, job.model_id)
        rec = read_record(folder)
        note = " (already done)"
        if rec is None:
            if on_start is not None:
                on_start(i, job)
            rec = _run_one(job, folder, one, error_prefix)
            note = ""
        records.append(rec)
        if progress is not None:
            reason = f": {rec['error']['reason']}" if rec.get("status") == "failed" and "error" in rec else ""
            progress(i + 1, total, f"{stage} {job.name}: {rec.get('status')}{note}{reason}")
    return records


def _run_one(job: ModelJob, folder: Path, one: Callable[[ModelJob, Path], dict], error_prefix: str) -> dict:
    try:
        fields = one(job, folder)
    except ModelError as err:
        return write_failed(folder, err, category=job.category, model_id=job.model_id, **job.failed_fields)
    except Exception as exc:
        if is_fatal(exc):
            raise  # disk full, not writable, out of memory, Blender missing: fail the task, record nothing
        err = ModelError(job.path, f"{error_prefix}{type(exc).__name__}: {exc}")
        return write_failed(folder, err, category=job.category, model_id=job.model_id, **job.failed_fields)
    return write_ok(folder, **fields)
