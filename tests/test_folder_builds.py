"""Builds from a user's folder: parameters checked before anything runs, ids that cannot clash,
changes of the folder rebuilt model by model, damaged datasets repaired by a re-run, and a
console that says what failed."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import luigi
import pytest
import trimesh

sys.path.insert(0, str(Path(__file__).parent))
from bad_inputs import BAD_PARAMETERS, CLASHES  # noqa: E402

from pipeline.dataset.verify import verify_dataset  # noqa: E402
from workflows import BuildDataset  # noqa: E402
from workflows.build_settings import BuildSettings  # noqa: E402
from workflows.console import Progress  # noqa: E402
from workflows.make_dataset import main as make_dataset  # noqa: E402
from workflows.steps import RUNS, read_runs  # noqa: E402
from workflows.validate import BuildParameterError  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TINY = dict(models_per_category=0, views=1, variants=1, image_size=64, out_size=64, batch_size=2)


def box(path: Path, extents: tuple[float, float, float]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=extents).export(str(path))


def run_build(src: Path, root: Path, **kw) -> bool:
    task = BuildDataset(source=str(src), work_dir=str(root / "work"), dataset_dir=str(root / "ds"), **{**TINY, **kw})
    return luigi.build([task], local_scheduler=True, workers=1, log_level="WARNING")


def settings(src: Path, root: Path) -> BuildSettings:
    return BuildSettings(
        source=str(src), work_dir=root / "work", dataset_dir=root / "ds", **{k: v for k, v in TINY.items()}
    )


def tree(ds: Path) -> dict[str, bytes]:
    return {p.relative_to(ds).as_posix(): p.read_bytes() for p in sorted(ds.rglob("*")) if p.is_file()}


# ---------------------------------------------------------------- parameters (no Blender)


@pytest.mark.parametrize("params, words", BAD_PARAMETERS)
def test_bad_parameters_stop_with_one_line_before_anything_runs(tmp_path: Path, params: dict, words: str) -> None:
    src = tmp_path / "src"
    box(src / "mug" / "a.obj", (1, 1, 1))
    with pytest.raises(BuildParameterError) as err:
        run_build(src, tmp_path, **params)
    assert words in str(err.value) and "\n" not in str(err.value)
    if "unknown" in words:
        assert str(err.value).endswith("it has: mug")
    assert not (tmp_path / "work").exists() and not (tmp_path / "ds").exists()


def test_missing_source_is_named(tmp_path: Path) -> None:
    with pytest.raises(BuildParameterError, match="--source '.*nowhere' is neither 'procedural' nor a folder"):
        run_build(tmp_path / "nowhere", tmp_path)


@pytest.mark.parametrize("names, words", CLASHES)
def test_files_that_would_be_one_model_are_named(tmp_path: Path, names: tuple[str, str], words: str) -> None:
    for name in names:
        box(tmp_path / "src" / "mug" / name, (1, 1, 1))
    box(tmp_path / "src" / "mug" / "other.obj", (1, 1, 1))
    with pytest.raises(BuildParameterError, match=re.escape(words)):
        run_build(tmp_path / "src", tmp_path)
    assert not (tmp_path / "work").exists()


def test_luigi_command_and_make_dataset_print_one_line(tmp_path: Path, capsys) -> None:
    src = tmp_path / "src"
    box(src / "mug" / "a.obj", (1, 1, 1))
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "luigi",
            "--module",
            "workflows",
            "BuildDataset",
            "--local-scheduler",
            "--source",
            str(src),
            "--categories",
            "mgu",
            "--work-dir",
            str(tmp_path / "w"),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    out = (r.stdout + r.stderr).strip()
    assert r.returncode != 0 and "Traceback" not in out, out
    assert out.splitlines()[-1] == f"error: --categories: unknown 'mgu' for source '{src}'; it has: mug"
    assert make_dataset(["--source", str(src), "--batch-size", "0"]) == 2
    assert capsys.readouterr().err.strip() == "error: --batch-size must be an integer >= 1, got 0"


def test_progress_line_rates_and_eta() -> None:
    p = Progress()
    assert p.line({"prepare": (0, 10), "shards": (0, 2)}, 100.0) == "prepare 0/10 | shards 0/2"
    assert p.line({"prepare": (4, 10), "shards": (0, 2)}, 102.0) == "prepare 4/10 2.00/s ETA 0:03 | shards 0/2"
    assert p.line({"prepare": (10, 10), "shards": (2, 2)}, 105.0) == "prepare 10/10 | shards 2/2"


def test_failures_are_loud_on_the_luigi_command(tmp_path: Path) -> None:
    """Only broken meshes (no Blender needed): the summary names each failure, no ':)', the
    build fails (nothing built), and --max-failed-fraction names the share."""
    src = tmp_path / "src" / "mug"
    src.mkdir(parents=True)
    (src / "cut.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    (src / "empty.obj").write_bytes(b"")
    cmd = [
        sys.executable,
        "-m",
        "luigi",
        "--module",
        "workflows",
        "BuildDataset",
        "--local-scheduler",
        "--source",
        str(tmp_path / "src"),
        "--models-per-category",
        "0",
        "--work-dir",
        str(tmp_path / "work"),
        "--dataset-dir",
        str(tmp_path / "ds"),
    ]
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    out = r.stdout + r.stderr
    assert r.returncode == 30, out  # a category with no model built fails the build
    assert ":)" not in out and "INFO" not in out
    assert "failed mug/cut at prepare: unreadable: face indices out of range" in out
    assert "failed mug/empty at prepare: empty mesh: file has 0 bytes" in out
    assert "2 of 2 models FAILED" in out
    assert "Informed scheduler" in (tmp_path / "work" / "luigi.log").read_text()  # Luigi's chatter
    r = subprocess.run(cmd + ["--max-failed-fraction", "0.5"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    out = r.stdout + r.stderr
    assert r.returncode == 30, out
    assert "mug: 2 of 2 models failed (100%) > --max-failed-fraction 0.5" in out and "BUILD FAILED" in out


# ---------------------------------------------------------------- changes and repairs (Blender)


@pytest.fixture(scope="module")
def changed(tmp_path_factory) -> dict:
    """A folder built, then changed (one mesh added, one changed, one removed) and rebuilt."""
    root = tmp_path_factory.mktemp("folder")
    src = root / "src"
    box(src / "mug" / "keep.obj", (1.0, 0.6, 0.4))
    box(src / "mug" / "edit.obj", (0.4, 0.4, 1.2))
    box(src / "mug" / "gone.obj", (1.0, 1.0, 0.3))
    box(src / "mug" / "_batches.obj", (0.7, 0.5, 0.5))  # named like the bookkeeping folder
    box(src / "knife" / "blade.obj", (1.5, 0.2, 0.05))
    assert run_build(src, root)
    s = settings(src, root)
    before = {p: p.stat().st_mtime_ns for p in (root / "work").rglob("record.json")}
    knife_shards = {p.name: p.stat().st_mtime_ns for p in (root / "ds" / "knife").glob("*.tar")}
    shutil.rmtree(root / "work" / RUNS)
    box(src / "mug" / "added.obj", (0.9, 0.9, 0.9))
    box(src / "mug" / "edit.obj", (0.5, 0.4, 1.0))
    (src / "mug" / "gone.obj").unlink()
    assert run_build(src, root)
    return {"root": root, "src": src, "s": s, "before": before, "knife_shards": knife_shards}


def test_changed_folder_rebuilds_exactly_the_changed_models(changed: dict) -> None:
    root, s = changed["root"], changed["s"]
    after = {p: p.stat().st_mtime_ns for p in (root / "work").rglob("record.json")}
    new = sorted({p.parent.name for p in after if p not in changed["before"]})
    assert [n.rsplit("-", 1)[0] for n in new] == ["added", "edit"]  # prepare, render, augment each
    assert all(changed["before"][p] == after[p] for p in changed["before"])  # nothing redone
    for stage in ("prepare", "render", "augment"):
        assert len([p for p in after if p not in changed["before"] and p.is_relative_to(s.stage_dir(stage))]) == 2
    ran = list(read_runs(root / "work"))  # task ids: family, then the first parameter values
    assert ran and all("_mug_" in t and "knife" not in t for t in ran), ran  # knife: nothing ran
    assert {t.split("_", 1)[0] for t in ran} == {"PrepareBatch", "RenderBatch", "AugmentBatch", "CategoryShards"}
    assert {p.name: p.stat().st_mtime_ns for p in (root / "ds" / "knife").glob("*.tar")} == changed["knife_shards"]
    cat = json.loads((root / "ds" / "mug" / "category.json").read_text())
    assert cat["models_built"] == 4 and cat["models_failed"] == 0
    keys = sorted(k for split in cat["splits"].values() for sh in split["shards"] for k in sh["keys"])
    assert keys == ["mug__batches", "mug_added", "mug_edit", "mug_keep"]
    assert verify_dataset(root / "ds") == []


def test_changed_build_equals_clean_build_and_rerun_repairs(changed: dict, tmp_path: Path) -> None:
    root, src = changed["root"], changed["src"]
    assert run_build(src, tmp_path)  # clean build of the changed folder
    clean = tree(tmp_path / "ds")
    assert tree(root / "ds") == clean
    ds = root / "ds"
    mug = sorted((ds / "mug").glob("*.tar"))
    with open(mug[0], "r+b") as f:
        f.truncate(4096)  # truncated
    (ds / "knife" / "train-00000.tar").unlink()  # missing
    (ds / "mug" / "test-00003.tar").write_bytes(b"stray")  # not listed: not the build's to delete
    (ds / "manifest.json").write_text((ds / "manifest.json").read_text().replace('"format": 1', '"format": 9'))
    assert len(verify_dataset(ds)) >= 3
    assert not run_build(src, root) and (ds / "mug" / "test-00003.tar").read_bytes() == b"stray"
    (ds / "mug" / "test-00003.tar").unlink()  # the user moves it away
    assert run_build(src, root)
    assert tree(ds) == clean
    # same-size edit: found by the default check when newer than category.json ...
    victim = ds / "knife" / "train-00000.tar"
    data = bytearray(victim.read_bytes())
    data[700] ^= 0xFF
    victim.write_bytes(bytes(data))
    assert run_build(src, root) and tree(ds) == clean
    # ... and only by --verify when its mtime was set back
    victim.write_bytes(bytes(data))
    old = (ds / "knife" / "category.json").stat().st_mtime_ns - 10**9
    os.utime(victim, ns=(old, old))
    assert run_build(src, root) and tree(ds) != clean
    assert run_build(src, root, verify=True) and tree(ds) == clean
