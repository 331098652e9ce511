"""End-to-end Luigi builds with real Blender renders at tiny settings.

One build is shared by the module (2 categories × 3 models × 2 views × 1 variant at 64²); the
tests read it back, rebuild it elsewhere, regenerate one category, and build a folder source
with a broken mesh.
"""

from __future__ import annotations

import subprocess
import sys
import tarfile
from pathlib import Path

import luigi
import numpy as np
import pytest
import webdataset as wds

from pipeline.core.hashing import file_sha256
from pipeline.core.schema import REQUIRED_MEMBERS
from pipeline.dataset.manifest import read_manifest
from pipeline.dataset.shards import list_shards
from pipeline.dataset.verify import verify_dataset
from workflows import BuildCategory, BuildDataset
from workflows.build_settings import BuildSettings

ROOT = Path(__file__).resolve().parents[1]
TINY = dict(
    models_per_category=3,
    views=2,
    variants=1,
    image_size=64,
    out_size=64,
    batch_size=2,
    shard_settings='{"max_samples_per_shard": 2}',
)
CATS = "knife,mug"


def build(root: Path, task_cls=BuildDataset, **kw) -> bool:
    params = {**TINY, "work_dir": str(root / "work"), "dataset_dir": str(root / "ds"), **kw}
    if task_cls is BuildDataset:
        params.setdefault("categories", CATS)
    return luigi.build([task_cls(**params)], local_scheduler=True, workers=1, log_level="WARNING")


def shard_state(ds: Path, category: str) -> dict[str, tuple[int, str]]:
    return {p.name: (p.stat().st_mtime_ns, file_sha256(p)) for p in list_shards(ds / category)}


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("build_a")
    assert build(root)
    return root


def test_build_settings_keys_chain() -> None:
    base = BuildSettings()
    pencil = BuildSettings(augment_overrides='{"grain": 0.2}')
    assert base.prepare_key() == pencil.prepare_key() and base.render_key() == pencil.render_key()
    assert base.augment_key() != pencil.augment_key() and base.shards_key() != pencil.shards_key()
    views = BuildSettings(views=3)
    assert views.prepare_key() == base.prepare_key() and views.render_key() != base.render_key()
    assert BuildSettings(work_dir=Path("/elsewhere")).category_settings_hash() == base.category_settings_hash()
    with pytest.raises(ValueError, match="no setting"):
        BuildSettings(augment_overrides='{"nope": 1}').augment_settings()


def test_shards_read_back_with_every_member(built: Path) -> None:
    ds = built / "ds"
    m = read_manifest(ds)
    assert sorted(m["categories"]) == ["knife", "mug"]
    assert verify_dataset(ds) == []
    for cat in ("knife", "mug"):
        entry = m["categories"][cat]
        assert entry["models_built"] + entry["models_failed"] == 3
        shards = list_shards(ds / cat)
        assert shards and all(p.name.split("-")[0] in ("train", "val", "test") for p in shards)
        # plain tarfile
        names = []
        for p in shards:
            with tarfile.open(p) as tar:
                names += tar.getnames()
        keys = sorted({n.split(".", 1)[0] for n in names})
        assert len(keys) == entry["models_built"]
        for key in keys:
            members = {n.split(".", 1)[1] for n in names if n.startswith(key + ".")}
            assert set(REQUIRED_MEMBERS) <= members
            assert {"sketch_00_00.png", "sketch_01_00.png"} <= members
        # webdataset, decoded
        for s in wds.WebDataset([str(p) for p in shards], shardshuffle=False).decode("l"):
            pts = s["points.npy"]
            assert pts.dtype == np.float32 and pts.shape[1] == 6 and pts.shape[0] >= 7000
            assert np.allclose(np.linalg.norm(pts[:, 3:], axis=1), 1, atol=1e-3)
            assert s["sketch_00_00.png"].shape == (64, 64) and s["sketch_00_00.png"].min() < 128
            meta = s["meta.json"]
            assert meta["category"] == cat and s["__key__"] == f"{cat}_{meta['model_id']}"
            assert len(meta["source_sha256"]) == 64 and not meta["source"].startswith("/")
            assert meta["normalization"]["scale"] > 0 and meta["part_labels"]
            assert len(s["cameras.json"]["views"]) == 2 and len(s["strokes.json"]["views"]) == 2


def test_rebuild_elsewhere_is_byte_identical(built: Path, tmp_path: Path) -> None:
    assert build(tmp_path)
    for cat in ("knife", "mug"):
        a, b = list_shards(built / "ds" / cat), list_shards(tmp_path / "ds" / cat)
        assert [p.name for p in a] == [p.name for p in b]
        assert all(x.read_bytes() == y.read_bytes() for x, y in zip(a, b))
    assert read_manifest(built / "ds")["checksum"] == read_manifest(tmp_path / "ds")["checksum"]


def test_regenerate_one_category_after_pencil_change(built: Path) -> None:
    ds, work = built / "ds", built / "work"
    knife_before, mug_before = shard_state(ds, "knife"), shard_state(ds, "mug")
    s = BuildSettings(
        **{k: v for k, v in TINY.items() if k != "shard_settings"},
        shard_overrides=TINY["shard_settings"],
        work_dir=work,
        dataset_dir=ds,
    )
    upstream = sorted((s.stage_dir("render") / "mug").glob("*/record.json")) + sorted(
        (s.stage_dir("prepare") / "mug").glob("*/record.json")
    )
    upstream_mtimes = [p.stat().st_mtime_ns for p in upstream]
    assert build(built, BuildCategory, category="mug", augment_settings='{"grain": 0.1, "tones": [[0.9, 1.0]]}')
    assert shard_state(ds, "knife") == knife_before  # untouched: same mtimes and hashes
    mug_after = shard_state(ds, "mug")
    assert {h for _, h in mug_after.values()}.isdisjoint({h for _, h in mug_before.values()})
    assert [p.stat().st_mtime_ns for p in upstream] == upstream_mtimes  # prepare/render not redone
    m = read_manifest(ds)
    assert len(m["settings"]) == 2  # knife and mug now differ
    assert m["categories"]["mug"]["settings"]["augment"]["grain"] == 0.1
    assert verify_dataset(ds) == []
    # the original settings again: mug comes back byte-identical to its first build
    assert build(built, BuildCategory, category="mug")
    assert {n: h for n, (_, h) in shard_state(ds, "mug").items()} == {n: h for n, (_, h) in mug_before.items()}
    assert len(read_manifest(ds)["settings"]) == 1


def test_split_assignment_stable_when_models_added(built: Path, tmp_path: Path) -> None:
    def splits(ds: Path) -> dict[str, str]:
        out = {}
        for p in list_shards(ds / "mug"):
            with tarfile.open(p) as tar:
                for n in tar.getnames():
                    out[n.split(".", 1)[0]] = p.name.split("-")[0]
        return out

    before = splits(built / "ds")
    assert build(tmp_path, BuildCategory, category="mug", models_per_category=5)
    after = splits(tmp_path / "ds")
    assert len(after) == 5 and all(after[k] == v for k, v in before.items())


def test_failed_model_is_recorded_and_category_completes(tmp_path: Path) -> None:
    from pipeline.shapes import generate

    src = tmp_path / "src" / "mug"
    src.mkdir(parents=True)
    generate("mug", 0).write(src / "good.obj")
    (src / "good.json").unlink()  # a plain folder source has no sidecar
    (src / "broken.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    assert build(tmp_path, BuildDataset, source=str(tmp_path / "src"), categories="mug")
    m = read_manifest(tmp_path / "ds")["categories"]["mug"]
    assert m["models_built"] == 1 and m["models_failed"] == 1
    fail = m["failed"][0]
    assert fail["model_id"] == "broken" and fail["stage"] == "prepare" and fail["reason"]
    assert fail["path"] == "mug/broken.obj"
    shards = list_shards(tmp_path / "ds" / "mug")
    samples = list(wds.WebDataset([str(p) for p in shards], shardshuffle=False).decode("l"))
    assert [s["__key__"] for s in samples] == ["mug_good"]
    assert {"points.npy", "strokes.json", "cameras.json", "meta.json", "sketch_00_00.png"} <= set(samples[0])
    r = subprocess.run(
        [sys.executable, "-m", "pipeline", "verify", str(tmp_path / "ds")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stdout
