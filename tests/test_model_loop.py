"""The one per-model loop and its error policy (pipeline.core.model_loop): a bad model is recorded
with its reason and the rest go on; a storage or environment error fails the batch with no record;
models already recorded are skipped; progress is reported after every model."""

from __future__ import annotations

import errno
import json
from pathlib import Path

import pytest

from pipeline.core.atomic import StorageError, storage_error, write_bytes
from pipeline.core.errors import ModelError
from pipeline.core.model_loop import ModelJob, is_fatal, run_models
from pipeline.core.records import read_record, write_ok

CAT = "mug"


def jobs(*ids: str) -> list[ModelJob]:
    return [
        ModelJob(CAT, mid, Path(f"/src/{mid}.obj"), item=mid, failed_fields={"source": {"path": mid}}) for mid in ids
    ]


def make(behaviour: dict[str, BaseException], calls: list[str]):
    """A stage function: writes data.bin, then raises what ``behaviour`` names for that model."""

    def one(job: ModelJob, folder: Path) -> dict:
        calls.append(job.model_id)
        write_bytes(folder / "data.bin", job.model_id.encode())
        exc = behaviour.get(job.model_id)
        if exc is not None:
            raise exc
        return {"category": job.category, "model_id": job.model_id, "n": len(calls)}

    return one


def test_bad_models_are_recorded_and_the_rest_go_on(tmp_path: Path) -> None:
    calls: list[str] = []
    progress: list[tuple[int, int, str]] = []
    bad = {"bad": ModelError("/src/bad.obj", "truncated: no end_header"), "bug": ValueError("odd input")}
    recs = run_models(
        "prepare",
        tmp_path,
        jobs("a", "bad", "bug", "b"),
        make(bad, calls),
        lambda d, t, m: progress.append((d, t, m)),
        error_prefix="x: ",
    )
    assert calls == ["a", "bad", "bug", "b"]
    assert [r["status"] for r in recs] == ["ok", "failed", "failed", "ok"]
    # the record on disk is what the loop returned, written by the loop (ok: the stage's fields)
    for mid, rec in zip(["a", "bad", "bug", "b"], recs):
        assert read_record(tmp_path / CAT / mid) == json.loads(json.dumps(rec))
    assert recs[0] == {"status": "ok", "category": CAT, "model_id": "a", "n": 1}
    assert recs[1]["error"] == {"path": "/src/bad.obj", "reason": "truncated: no end_header"}
    assert recs[1]["source"] == {"path": "bad"} and recs[1]["model_id"] == "bad"
    # an unexpected exception is blamed on the job's input, its type kept in the reason
    assert recs[2]["error"] == {"path": "/src/bug.obj", "reason": "x: ValueError: odd input"}
    assert [p[:2] for p in progress] == [(1, 4), (2, 4), (3, 4), (4, 4)]
    assert progress[0][2] == "prepare mug/a: ok"
    assert progress[1][2] == "prepare mug/bad: failed: truncated: no end_header"


FATAL = {
    "disk full": storage_error("/w/mug/s/data.bin", OSError(errno.ENOSPC, "No space left on device")),
    "read-only": storage_error("/w/mug/s/data.bin", OSError(errno.EROFS, "Read-only file system")),
    "permission": storage_error("/w/mug/s/data.bin", PermissionError(errno.EACCES, "denied")),
    "I/O error": OSError(errno.EIO, "Input/output error"),
    "out of memory": MemoryError(),
    "bpy missing": ModuleNotFoundError("No module named 'bpy'"),
    "interrupted": KeyboardInterrupt(),
}


@pytest.mark.parametrize("exc", list(FATAL.values()), ids=list(FATAL))
def test_storage_and_environment_errors_fail_the_batch(tmp_path: Path, exc: BaseException) -> None:
    calls: list[str] = []
    with pytest.raises(type(exc)) as raised:
        run_models("render", tmp_path, jobs("a", "s", "b"), make({"s": exc}, calls))
    assert raised.value is exc  # re-raised as it was: its message names the file
    assert calls == ["a", "s"]  # nothing after it ran
    assert read_record(tmp_path / CAT / "a")["status"] == "ok"
    # no record for the model it hit: a re-run after the fix builds it instead of skipping it
    assert not (tmp_path / CAT / "s" / "record.json").exists()
    assert not (tmp_path / CAT / "b").exists()
    assert is_fatal(exc)


def test_policy_classification() -> None:
    assert not is_fatal(ModelError("/x", "bad"))
    assert not is_fatal(ValueError("bug on odd input"))
    assert not is_fatal(RuntimeError("Blender error on one model"))
    assert is_fatal(StorageError(errno.ENOSPC, "cannot write x: disk full"))


def test_recorded_models_are_skipped(tmp_path: Path) -> None:
    write_ok(tmp_path / CAT / "a", category=CAT, model_id="a", n=99)
    (tmp_path / CAT / "b").mkdir(parents=True)
    (tmp_path / CAT / "b" / "record.json").write_text(
        json.dumps({"status": "failed", "error": {"path": "/src/b.obj", "reason": "old"}})
    )
    calls: list[str] = []
    started: list[tuple[int, str]] = []
    progress: list[tuple[int, int, str]] = []
    recs = run_models(
        "augment",
        tmp_path,
        jobs("a", "b", "c"),
        make({}, calls),
        lambda d, t, m: progress.append((d, t, m)),
        on_start=lambda i, job: started.append((i, job.model_id)),
    )
    assert calls == ["c"] and started == [(2, "c")]  # done models (ok or failed) are not redone
    assert recs[0]["n"] == 99 and recs[1]["error"]["reason"] == "old" and recs[2]["status"] == "ok"
    assert not (tmp_path / CAT / "a" / "data.bin").exists()
    assert [p[:2] for p in progress] == [(1, 3), (2, 3), (3, 3)]
    assert progress[0][2] == "augment mug/a: ok (already done)"


def test_record_is_written_last(tmp_path: Path) -> None:
    """The record only appears once the stage function has returned (its files are all there)."""
    seen = []

    def one(job: ModelJob, folder: Path) -> dict:
        write_bytes(folder / "data.bin", b"x")
        seen.append((folder / "record.json").exists())
        return {"model_id": job.model_id}

    run_models("prepare", tmp_path, jobs("a"), one)
    assert seen == [False] and read_record(tmp_path / CAT / "a") == {"status": "ok", "model_id": "a"}
