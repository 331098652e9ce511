"""Disk-full and permission errors: a clear message naming the file, no half file left, and a
full disk or read-only output fails the batch (to be re-run) instead of marking models as bad,
in every stage with a per-model loop: prepare, render (inside the Blender worker) and augment."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import pwd
import subprocess
import sys
import tempfile
from pathlib import Path

import luigi
import pytest
import trimesh
from PIL import Image, ImageDraw

sys.path.insert(0, str(Path(__file__).parent))
from as_user import call_as  # noqa: E402

from augment.batch import augment_batch
from augment.settings import AugmentSettings
from pipeline.core.atomic import StorageError, storage_error, write_bytes
from pipeline.core.records import ModelRef, read_record, write_ok
from pipeline.dataset.manifest import read_manifest
from pipeline.prepare.batch import PrepareSettings, prepare_batch
from render.batch import render_batch
from render.settings import RenderSettings
from workflows import BuildCategory


def test_storage_errors_are_translated() -> None:
    full = storage_error("/data/x.npy", OSError(errno.ENOSPC, "No space left on device"))
    assert isinstance(full, StorageError) and full.errno == errno.ENOSPC
    assert str(full).endswith(
        "cannot write /data/x.npy: disk full (no space left on device); "
        "free space or point --work-dir/--dataset-dir elsewhere"
    )
    assert "read-only filesystem" in str(storage_error("/d/y", OSError(errno.EROFS, "ro")))
    assert "permission denied" in str(storage_error("/d/y", PermissionError(errno.EACCES, "denied")))
    other = OSError(errno.EIO, "I/O error")
    assert storage_error("/d/y", other) is other  # not a storage problem the user can fix: unchanged


@pytest.fixture
def small_disk():
    """A 256 KiB tmpfs (needs root and mount rights; skipped elsewhere)."""
    mnt = Path(tempfile.mkdtemp(prefix="small-disk-"))
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)], capture_output=True)
    if r.returncode != 0:
        os.rmdir(mnt)
        pytest.skip(f"cannot mount a small tmpfs here: {r.stderr.decode().strip()}")
    yield mnt
    subprocess.run(["umount", str(mnt)], check=True)
    os.rmdir(mnt)


def test_disk_full_names_file_and_leaves_nothing(small_disk: Path) -> None:
    target = small_disk / "out" / "big.bin"
    with pytest.raises(StorageError, match=rf"cannot write {target}: disk full"):
        write_bytes(target, b"\0" * (1 << 20))
    assert os.listdir(target.parent) == []  # neither the target nor the temp file


def test_disk_full_fails_the_batch_not_the_model(small_disk: Path, tmp_path: Path) -> None:
    src = tmp_path / "box.obj"
    trimesh.creation.box().export(src)
    ref = ModelRef("mug", "box", src, "folder")
    with pytest.raises(StorageError, match="disk full"):
        prepare_batch([ref], small_disk / "stage", PrepareSettings(resolution=1000))
    # no record: once space is freed the model is prepared, not skipped as "failed"
    assert not (small_disk / "stage" / "mug" / "box" / "record.json").exists()


def test_permission_denied_names_file() -> None:
    if os.geteuid() != 0:
        pytest.skip("needs root to drop to another user")
    nobody = pwd.getpwnam("nobody")
    folder = Path(tempfile.mkdtemp(prefix="perm-"))
    try:
        folder.chmod(0o755)  # root's folder: others may enter but not write
        target = folder / "cat" / "record.json"
        (folder / "cat").mkdir()

        def write() -> str:
            write_bytes(target, b"{}")
            return "written"

        msg = call_as((nobody.pw_uid, nobody.pw_gid), write)
        assert msg.startswith("StorageError: ") and msg.endswith(
            f"cannot write {target}: permission denied; make the folder writable by this user"
        ), msg
        assert not target.exists()
    finally:
        subprocess.run(["rm", "-rf", str(folder)], check=True)


def records_under(folder: Path) -> list[Path]:
    return sorted(Path(folder).rglob("record.json"))


@contextlib.contextmanager
def broken_folder(folder: Path, how: str):
    """``folder`` as a real tmpfs mount that is full (ENOSPC) or read-only (EROFS); needs root and
    mount rights (skipped elsewhere; the SKETCH_FAULT_ERRNO_AT build test below runs anywhere)."""
    folder.mkdir(parents=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(folder)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here: {r.stderr.decode().strip()}")
    try:
        if how == "full":
            with contextlib.suppress(OSError), open(folder / "filler", "wb") as f:
                while True:
                    f.write(b"\0" * 4096)
                    f.flush()
        else:
            subprocess.run(["mount", "-o", "remount,ro", str(folder)], check=True)
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=True)


BROKEN = {"full": "disk full", "read-only": "read-only filesystem"}


@pytest.mark.parametrize("how", list(BROKEN))
def test_render_storage_error_fails_the_batch(tmp_path: Path, how: str) -> None:
    """Inside the Blender worker: the error comes back to render_batch and is raised there, even
    with on_crash="record" (the default), and no model is recorded as bad."""
    mesh = tmp_path / "box.ply"
    trimesh.creation.box().export(mesh)
    stage = tmp_path / "render"
    with broken_folder(stage / "mug" / "a", how):
        with pytest.raises(StorageError, match=rf"cannot write {stage}/mug/a/view_00.png: {BROKEN[how]}"):
            render_batch("mug", [("a", mesh), ("b", mesh)], stage, RenderSettings(views=1, image_size=64), 0)
        assert records_under(stage) == []
    assert not list((stage / "mug").glob(".render-job-*"))  # the job folder is cleaned up


def fake_render(folder: Path) -> Path:
    """A finished render folder: one line drawing and an ok record."""
    img = Image.new("L", (64, 64), 255)
    ImageDraw.Draw(img).rectangle([12, 12, 50, 44], outline=0, width=2)
    folder.mkdir(parents=True)
    img.save(folder / "view_00.png")
    write_ok(folder, category="mug")
    return folder


@pytest.mark.parametrize("how", list(BROKEN))
def test_augment_storage_error_fails_the_batch(tmp_path: Path, how: str) -> None:
    items = [(m, fake_render(tmp_path / "render" / m)) for m in ("a", "b")]
    stage = tmp_path / "augment"
    settings = AugmentSettings(variants=1, out_size=64)
    with broken_folder(stage / "mug" / "a", how):
        with pytest.raises(StorageError, match=rf"cannot write {stage}/mug/a/sketch_00_00.png: {BROKEN[how]}"):
            augment_batch("mug", items, stage, settings, 0)
        assert records_under(stage) == []
    # once the disk is fixed the same call builds both models
    assert [r["status"] for r in augment_batch("mug", items, stage, settings, 0)] == ["ok", "ok"]


def test_build_storage_errors_fail_the_task_not_the_model(tmp_path: Path, monkeypatch) -> None:
    """Luigi end to end, with the SKETCH_FAULT_ERRNO_AT hook (no root needed): a full disk in
    render, then a read-only augment output, fail the build without recording a bad model; the
    re-run once storage is fixed builds every model."""
    params = dict(
        category="mug",
        models_per_category=2,
        batch_size=2,
        views=1,
        variants=1,
        image_size=64,
        out_size=64,
        work_dir=str(tmp_path / "work"),
        dataset_dir=str(tmp_path / "ds"),
    )
    work = tmp_path / "work"

    def build(fault: str | None) -> bool:
        if fault:
            monkeypatch.setenv("SKETCH_FAULT_ERRNO_AT", fault)
        else:
            monkeypatch.delenv("SKETCH_FAULT_ERRNO_AT", raising=False)
        return luigi.build([BuildCategory(**params)], local_scheduler=True, workers=1, log_level="WARNING")

    def statuses(stage: str) -> list[str]:
        return [read_record(p.parent)["status"] for d in work.glob(f"{stage}-*") for p in records_under(d)]

    assert not build("*/render-*/view_00.png:ENOSPC")
    assert statuses("prepare") == ["ok", "ok"] and statuses("render") == []
    assert not build("*/augment-*/sketch_00_00.png:EROFS")
    assert statuses("render") == ["ok", "ok"] and statuses("augment") == []
    assert build(None)
    cat = read_manifest(tmp_path / "ds")["categories"]["mug"]
    assert cat["models_built"] == 2 and cat["models_failed"] == 0, json.dumps(cat["failed"])


def test_worker_errors_come_back_as_the_same_kind() -> None:
    from render.job import fatal_from_json, fatal_to_json

    full = storage_error("/w/a.png", OSError(errno.ENOSPC, "No space left on device"))
    back = fatal_from_json(json.loads(json.dumps(fatal_to_json(full))))
    assert isinstance(back, StorageError) and back.errno == errno.ENOSPC and str(back) == str(full)
    assert isinstance(fatal_from_json(fatal_to_json(OSError(errno.EIO, "I/O error"))), OSError)
    assert isinstance(fatal_from_json(fatal_to_json(ModuleNotFoundError("No module named 'bpy'"))), ImportError)
    assert isinstance(fatal_from_json(fatal_to_json(MemoryError())), MemoryError)
