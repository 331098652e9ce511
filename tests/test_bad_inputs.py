"""The bad-input corpus (tests/bad_inputs.py): every bad file gets its own clear failure reason,
naming the file, and the rest of the batch / build goes on."""

from __future__ import annotations

import os
import pwd
import shutil
import sys
import tempfile
from pathlib import Path

import luigi
import pytest
import webdataset as wds

sys.path.insert(0, str(Path(__file__).parent))
from as_user import call_as  # noqa: E402
from bad_inputs import write_corpus, write_good, write_unreadable, write_unusual_good  # noqa: E402

from pipeline.dataset.manifest import read_manifest  # noqa: E402
from pipeline.dataset.shards import list_shards  # noqa: E402
from pipeline.prepare.batch import PrepareSettings, prepare_batch  # noqa: E402
from pipeline.sources.layouts import list_models  # noqa: E402
from pipeline.sources.mesh_io import _DENIED, load_mesh  # noqa: E402
from workflows import BuildDataset  # noqa: E402


def test_corpus_fails_file_by_file_in_prepare(tmp_path: Path) -> None:
    src = tmp_path / "src" / "mug"
    expect = write_corpus(src)
    good = write_good(src) + write_unusual_good(src)
    assert len(expect) >= 40
    refs = list_models(str(tmp_path / "src"), "mug", None, 0, tmp_path / "work")
    # every entry named like a mesh is listed, including the folder, the FIFO and the dead link
    assert sorted(r.model_id for r in refs) == sorted([*expect, *good])
    records = prepare_batch(refs, tmp_path / "stage", PrepareSettings())
    by_id = {r.model_id: (r, rec) for r, rec in zip(refs, records)}
    assert by_id["tiny"][1]["normalization"]["scale"] < 1e-4  # read at its own scale, normalized
    for mid in good:
        assert by_id[mid][1]["status"] == "ok", by_id[mid][1]
    for mid, words in expect.items():
        ref, rec = by_id[mid]
        assert rec["status"] == "failed", mid
        assert rec["error"]["path"] == str(ref.path)
        assert words.lower() in rec["error"]["reason"].lower(), (mid, rec["error"]["reason"])


def _nobody() -> tuple[int, int]:
    entry = pwd.getpwnam("nobody")
    return entry.pw_uid, entry.pw_gid


def _load_as(uid_gid: tuple[int, int] | None, path: Path) -> str:
    """load_mesh(path) as ``uid_gid``; returns the error text."""

    def load() -> str:
        load_mesh(path)
        return "loaded"

    return call_as(uid_gid, load)


def test_unreadable_file_names_permission(tmp_path: Path) -> None:
    # root reads mode-000 files anyway, so the real check runs as "nobody" in a forked child
    if os.geteuid() == 0:
        try:
            who = _nobody()
        except KeyError:
            pytest.skip("running as root and there is no 'nobody' user to drop privileges to")
    else:
        who = None
    # a folder "nobody" can enter (pytest's tmp root is private to root)
    folder = Path(tempfile.mkdtemp(prefix="bad-inputs-"))
    try:
        folder.chmod(0o755)
        path = folder / "locked.obj"
        write_unreadable(path)
        assert _load_as(who, path) == f"ModelError: {path}: unreadable: {_DENIED}"
        hidden = folder / "private"  # a folder above the file that can't be entered
        hidden.mkdir()
        (hidden / "box.obj").write_text("v 0 0 0\n")
        hidden.chmod(0)
        assert (
            _load_as(who, hidden / "box.obj")
            == f"ModelError: {hidden / 'box.obj'}: unreadable: {_DENIED} on a folder above it"
        )
    finally:
        if (folder / "private").exists():
            (folder / "private").chmod(0o700)
        shutil.rmtree(folder)


def test_build_with_bad_corpus_lists_every_failure(tmp_path: Path) -> None:
    """Whole Luigi build (real Blender for the two good models, ~11 s)."""
    src = tmp_path / "src" / "mug"
    expect = write_corpus(src)
    good = write_good(src) + write_unusual_good(src)
    names = {p.stem: p.name for p in src.iterdir()}
    ok = luigi.build(
        [
            BuildDataset(
                source=str(tmp_path / "src"),
                models_per_category=0,
                views=1,
                variants=1,
                image_size=64,
                out_size=64,
                batch_size=8,
                work_dir=str(tmp_path / "work"),
                dataset_dir=str(tmp_path / "ds"),
            )
        ],
        local_scheduler=True,
        workers=1,
        log_level="WARNING",
    )
    assert ok
    cat = read_manifest(tmp_path / "ds")["categories"]["mug"]
    failed = {f["model_id"]: f for f in cat["failed"]}
    assert sorted(failed) == sorted(expect)
    for mid, words in expect.items():
        f = failed[mid]
        assert f["stage"] == "prepare" and f["path"] == f"mug/{names[mid]}", f
        assert words.lower() in f["reason"].lower(), (mid, f["reason"])
    assert cat["models_built"] == len(good) and cat["models_failed"] == len(expect)
    keys = [
        s["__key__"] for s in wds.WebDataset([str(p) for p in list_shards(tmp_path / "ds" / "mug")], shardshuffle=False)
    ]
    assert sorted(keys) == sorted(f"mug_{m}" for m in good)
