"""Shard writing and reading on synthetic per-model stage folders (no Blender)."""

from __future__ import annotations

import io
import json
import tarfile
from pathlib import Path

import numpy as np
import pytest
import webdataset as wds
from PIL import Image

from pipeline.core.atomic import write_json, write_npy
from pipeline.core.splits import split_of
from pipeline.dataset.shards import (
    ModelDirs,
    ShardSettings,
    assemble_sample,
    iter_shard,
    list_shards,
    write_category_shards,
)


def make_model_dirs(
    root: Path,
    category: str,
    model_id: str,
    views: int = 2,
    variants: int = 2,
    n_points: int = 8000,
    bad: str | None = None,
) -> ModelDirs:
    """Fake prepare/render/augment folders shaped like the real stages' outputs."""
    rng = np.random.default_rng(abs(hash((category, model_id))) % 2**32)
    prep = root / "prepare" / category / model_id
    rend = root / "render" / category / model_id
    aug = root / "augment" / category / model_id
    pts = rng.normal(size=(n_points, 6)).astype(np.float32)
    write_npy(prep / "samples.npy", pts)
    write_json(
        prep / "record.json",
        {
            "status": "ok",
            "source": {"path": str(root / "src" / f"{model_id}.obj"), "sha256": "ab" * 32},
            "normalization": {"center": [0, 0, 0], "scale": 1.0},
            "parts": [{"label": "body"}, {"label": "handle"}],
            "bodies": 2,
        },
    )
    write_json(rend / "cameras.json", {"image_size": 64, "views": [{"azimuth_deg": 30.0 * v} for v in range(views)]})
    write_json(rend / "record.json", {"status": "ok"})
    aug.mkdir(parents=True, exist_ok=True)
    for v in range(views):
        for k in range(variants):
            img = Image.fromarray((rng.random((32, 32)) * 255).astype(np.uint8), "L")
            img.save(aug / f"sketch_{v:02d}_{k:02d}.png")
    write_json(
        aug / "strokes.json",
        {"out_size": 32, "views": [{"variants": [{"width": 2.0, "strokes": [[[1, 2], [3, 4]]]}] * variants}] * views},
    )
    write_json(aug / "record.json", {"status": "ok"})
    if bad == "points":
        (prep / "samples.npy").write_bytes(b"not an npy file")
    return ModelDirs(model_id, prep, rend, aug)


def test_split_is_stable_and_roughly_proportional() -> None:
    ids = [f"{i:05d}" for i in range(2000)]
    splits = [split_of("mug", m) for m in ids]
    assert [split_of("mug", m) for m in ids[:50]] == splits[:50]  # pure function of the id
    frac = {s: splits.count(s) / len(ids) for s in ("train", "val", "test")}
    assert 0.76 < frac["train"] < 0.84 and 0.07 < frac["val"] < 0.13 and 0.07 < frac["test"] < 0.13
    assert split_of("mug", "x", (0, 0, 1)) == "test"


def test_sample_members_and_meta(tmp_path: Path) -> None:
    d = make_model_dirs(tmp_path, "mug", "00003", n_points=20000)
    s = assemble_sample(
        "mug", d, ShardSettings(points=9000), seed=5, settings_hash="h123", portable=lambda p: Path(p).name
    )
    assert s.key == "mug_00003"
    assert sorted(s.members) == [
        "cameras.json",
        "meta.json",
        "points.npy",
        "sketch_00_00.png",
        "sketch_00_01.png",
        "sketch_01_00.png",
        "sketch_01_01.png",
        "strokes.json",
    ]
    pts = np.load(io.BytesIO(s.members["points.npy"]))
    assert pts.dtype == np.float32 and pts.shape == (9000, 6)
    meta = json.loads(s.members["meta.json"])
    assert meta["source"] == "00003.obj" and meta["source_sha256"] == "ab" * 32
    assert meta["part_labels"] == ["body", "handle"] and meta["seed"] == 5 and meta["settings_hash"] == "h123"
    assert meta["split"] == split_of("mug", "00003")
    assert meta["bodies"] == 2  # the prepared mesh's body count, carried from the prepare record


def test_shards_bytes_fixed_and_readable_by_webdataset(tmp_path: Path) -> None:
    models = [make_model_dirs(tmp_path, "mug", f"{i:05d}") for i in range(12)]
    st = ShardSettings(max_samples_per_shard=3, split_fractions=(0.5, 0.25, 0.25))
    a = write_category_shards("mug", models, tmp_path / "a" / "mug", st, 0, "h")
    write_category_shards("mug", models, tmp_path / "b" / "mug", st, 0, "h")
    names_a = [p.name for p in list_shards(tmp_path / "a" / "mug")]
    assert names_a == [p.name for p in list_shards(tmp_path / "b" / "mug")]
    for n in names_a:
        assert (tmp_path / "a" / "mug" / n).read_bytes() == (tmp_path / "b" / "mug" / n).read_bytes()
    assert all(i.samples <= 3 for infos in a.shards.values() for i in infos)
    assert sum(i.samples for infos in a.shards.values() for i in infos) == 12
    # fixed headers, sorted members
    with tarfile.open(tmp_path / "a" / "mug" / names_a[0]) as tar:
        infos = tar.getmembers()
        assert all(m.mtime == 0 and m.uid == 0 and m.gid == 0 and m.uname == "" and m.mode == 0o644 for m in infos)
        assert [m.name for m in infos] == sorted(m.name for m in infos)
    # webdataset reads every member, decoded
    urls = [str(p) for p in list_shards(tmp_path / "a" / "mug")]
    seen = []
    for s in wds.WebDataset(urls, shardshuffle=False, empty_check=False).decode("l"):
        seen.append(s["__key__"])
        assert s["points.npy"].shape == (8000, 6)
        assert s["sketch_01_01.png"].shape == (32, 32)
        assert s["meta.json"]["category"] == "mug" and "views" in s["cameras.json"]
        assert len(s["strokes.json"]["views"]) == 2
    assert sorted(seen) == [f"mug_{i:05d}" for i in range(12)]
    # each shard holds only its split
    for infos in a.shards.values():
        for i in infos:
            for key, members in iter_shard(tmp_path / "a" / "mug" / i.name):
                assert json.loads(members["meta.json"])["split"] == i.split


def test_unchanged_shards_keep_mtime_and_stale_are_removed(tmp_path: Path) -> None:
    models = [make_model_dirs(tmp_path, "mug", f"{i:05d}") for i in range(6)]
    st = ShardSettings(max_samples_per_shard=100)
    out = tmp_path / "ds" / "mug"
    write_category_shards("mug", models, out, st, 0, "h")
    before = {p.name: p.stat().st_mtime_ns for p in list_shards(out)}
    again = write_category_shards("mug", models, out, st, 0, "h")
    assert again.written == [] and {p.name: p.stat().st_mtime_ns for p in list_shards(out)} == before
    train_models = [m for m in models if split_of("mug", m.model_id) == "train"]
    third = write_category_shards("mug", train_models, out, st, 0, "h")
    assert set(p.name for p in list_shards(out)) == {"train-00000.tar"}
    assert set(third.removed) == set(before) - {"train-00000.tar"}
    assert not any(p.name.startswith(".staging") for p in out.iterdir())


def test_bad_model_is_recorded_not_raised(tmp_path: Path) -> None:
    models = [
        make_model_dirs(tmp_path, "mug", "00000"),
        make_model_dirs(tmp_path, "mug", "00001", bad="points"),
        make_model_dirs(tmp_path, "mug", "00002", n_points=100),
    ]
    res = write_category_shards("mug", models, tmp_path / "ds" / "mug", ShardSettings(), 0, "h")
    assert [f["model_id"] for f in res.failed] == ["00001", "00002"]
    assert "samples.npy" in res.failed[0]["path"] and "surface samples" in res.failed[0]["reason"]
    assert "at least 7000" in res.failed[1]["reason"]
    assert sum(i.samples for infos in res.shards.values() for i in infos) == 1


def test_byte_bound_splits_shards(tmp_path: Path) -> None:
    models = [make_model_dirs(tmp_path, "mug", f"{i:05d}") for i in range(8)]
    st = ShardSettings(max_bytes_per_shard=450_000 // 2 + 100_000, split_fractions=(1, 0, 0))
    res = write_category_shards("mug", models, tmp_path / "ds" / "mug", st, 0, "h")
    assert [i.samples for i in res.shards["train"]] == [1] * 8  # each sample ~200 kB of points
    st2 = ShardSettings(max_bytes_per_shard=10_000_000, split_fractions=(1, 0, 0))
    res2 = write_category_shards("mug", models, tmp_path / "ds2" / "mug", st2, 0, "h")
    assert [i.samples for i in res2.shards["train"]] == [8]
    st3 = ShardSettings(max_bytes_per_shard=450_000, split_fractions=(1, 0, 0))
    res3 = write_category_shards("mug", models, tmp_path / "ds3" / "mug", st3, 0, "h")
    assert [i.samples for i in res3.shards["train"]] == [2] * 4
    assert all(i.bytes <= 450_000 for i in res3.shards["train"])


@pytest.mark.parametrize("fractions", [(1, 0, 0), (0, 0, 1)])
def test_empty_splits_write_no_shards(tmp_path: Path, fractions) -> None:
    models = [make_model_dirs(tmp_path, "mug", f"{i:05d}") for i in range(3)]
    res = write_category_shards(
        "mug", models, tmp_path / "ds" / "mug", ShardSettings(split_fractions=fractions), 0, "h"
    )
    assert sum(len(v) > 0 for v in res.shards.values()) == 1
