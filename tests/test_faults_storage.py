"""Disk-full and permission errors: a clear message naming the file, no half file left, and a
full disk fails the batch (to be re-run) instead of marking models as bad."""

from __future__ import annotations

import errno
import os
import pwd
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
import trimesh

sys.path.insert(0, str(Path(__file__).parent))
from as_user import call_as  # noqa: E402

from pipeline.core.atomic import StorageError, storage_error, write_bytes
from pipeline.core.records import ModelRef
from pipeline.prepare.batch import PrepareSettings, prepare_batch


def test_storage_errors_are_translated() -> None:
    full = storage_error("/data/x.npy", OSError(errno.ENOSPC, "No space left on device"))
    assert isinstance(full, StorageError) and full.errno == errno.ENOSPC
    assert str(full).endswith("cannot write /data/x.npy: disk full (no space left on device); "
                              "free space or point --work-dir/--dataset-dir elsewhere")
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
            f"cannot write {target}: permission denied; make the folder writable by this user"), msg
        assert not target.exists()
    finally:
        subprocess.run(["rm", "-rf", str(folder)], check=True)
