"""Category fragments merge into a manifest that reflects what is on disk."""

from __future__ import annotations

from pathlib import Path

from test_shards import make_model_dirs

from pipeline.dataset.manifest import category_fragment, content_checksum, read_manifest, write_fragment, write_manifest
from pipeline.dataset.shards import ShardSettings, write_category_shards


def build(root: Path, ds: Path, category: str, n: int, settings: dict, failed: list[dict] | None = None) -> dict:
    models = [make_model_dirs(root, category, f"{i:05d}") for i in range(n)]
    res = write_category_shards(
        category,
        models,
        ds / category,
        ShardSettings(max_samples_per_shard=2),
        0,
        "h",
        before_cleanup=lambda r: write_fragment(
            ds / category,
            category_fragment(
                category, r, settings, "hash-" + str(sorted(settings.items())), n + len(failed or []), failed or []
            ),
        ),
    )
    return res


def test_manifest_counts_failures_and_checksum(tmp_path: Path) -> None:
    ds = tmp_path / "ds"
    failed = [
        {"model_id": "00099", "stage": "render", "path": "prepare/mug/00099/mesh.ply", "reason": "blender crashed"}
    ]
    build(tmp_path / "w", ds, "mug", 5, {"views": 2}, failed)
    build(tmp_path / "w", ds, "car", 3, {"views": 2})
    m = write_manifest(ds)
    assert m == read_manifest(ds)
    assert set(m["categories"]) == {"car", "mug"}
    mug = m["categories"]["mug"]
    assert mug["models_built"] == 5 and mug["models_failed"] == 1 and mug["models_requested"] == 6
    assert mug["failed"][0]["reason"] == "blender crashed" and mug["failed"][0]["stage"] == "render"
    assert sum(mug["splits"][s]["samples"] for s in ("train", "val", "test")) == 5
    for s in ("train", "val", "test"):
        for shard in mug["splits"][s]["shards"]:
            assert len(shard["sha256"]) == 64 and (ds / "mug" / shard["name"]).stat().st_size == shard["bytes"]
    assert m["totals"]["models_built"] == 8 and m["totals"]["models_failed"] == 1
    assert m["project_version"] and len(m["settings"]) == 1
    assert m["checksum"] == content_checksum(m)
    # different settings in one category: both settings sets are listed
    build(tmp_path / "w", ds, "car", 3, {"views": 3})
    m2 = write_manifest(ds)
    assert len(m2["settings"]) == 2 and m2["checksum"] != m["checksum"]
    assert m2["categories"]["mug"] == m["categories"]["mug"]


def test_manifest_is_independent_of_location(tmp_path: Path) -> None:
    build(tmp_path / "w", tmp_path / "a", "mug", 4, {"views": 2})
    build(tmp_path / "w", tmp_path / "b", "mug", 4, {"views": 2})
    assert (tmp_path / "a" / "manifest.json").exists() is False
    assert write_manifest(tmp_path / "a")["checksum"] == write_manifest(tmp_path / "b")["checksum"]
    assert (tmp_path / "a" / "manifest.json").read_bytes() == (tmp_path / "b" / "manifest.json").read_bytes()
