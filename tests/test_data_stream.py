import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import write_fixture_shards  # noqa: E402

from pipeline.core.errors import ModelError
from train.augmentation import Jitter, jitter_image
from train.data import DataSettings, ShardStream, make_loader, shard_urls, splits_with_shards


@pytest.fixture(scope="module")
def shards(tmp_path_factory):
    return write_fixture_shards(tmp_path_factory.mktemp("ds"), counts={"train": 8, "val": 2, "test": 2}, n_points=1200)


SET = DataSettings(max_views=2, n_points=500, image_size=32, shuffle_buffer=4)


def test_train_batches_shapes_and_ink(shards):
    loader = make_loader(shards, "knife", "train", SET, seed=1, batch_size=3)
    batch = next(iter(loader))
    assert batch["images"].shape == (3, 2, 1, 32, 32)
    assert batch["points"].shape == (3, 500, 6)
    assert batch["view_mask"][:, 0].all()  # at least one view per sample
    imgs = batch["images"][batch["view_mask"]]
    assert 0 < imgs.mean() < 0.5 and imgs.max() > 0.5  # inverted: mostly paper (0), some ink
    normals = batch["points"][..., 3:]
    assert torch.allclose(normals.norm(dim=-1), torch.ones(3, 500), atol=1e-5)


def test_train_stream_is_seeded_and_endless(shards):
    def take(seed, n):
        it = iter(make_loader(shards, "knife", "train", SET, seed=seed, batch_size=2))
        return [next(it) for _ in range(n)]

    a, b, c = take(3, 6), take(3, 6), take(4, 6)  # 12 samples > 8 in the split: wraps to epoch 2
    assert all(torch.equal(x["images"], y["images"]) and x["key"] == y["key"] for x, y in zip(a, b))
    assert any(x["key"] != y["key"] or not torch.equal(x["images"], y["images"]) for x, y in zip(a, c))


def test_rank_split_is_disjoint_and_covering(shards):
    urls = shard_urls(shards, "knife", "train")
    keys = []
    for rank in range(2):
        stream = iter(ShardStream(urls, SET, seed=0, train=True, rank=rank, world=2))
        keys.append({next(stream)["key"] for _ in range(4)})
    assert not keys[0] & keys[1]
    assert len(keys[0] | keys[1]) == 8


def test_eval_is_single_deterministic_pass(shards):
    run = [list(make_loader(shards, "knife", "test", SET, seed=0, batch_size=1, train=False)) for _ in range(2)]
    assert [b["key"][0] for b in run[0]] == ["knife_00010", "knife_00011"]
    assert all(torch.equal(x["points"], y["points"]) for x, y in zip(*run))


def test_missing_split_names_folder(tmp_path):
    with pytest.raises(ModelError, match="no train"):
        shard_urls(tmp_path, "knife", "train")


def test_all_splits_are_those_with_shards(shards, tmp_path):
    assert splits_with_shards(shards, "knife", "all") == ["train", "val", "test"]
    folder = tmp_path / "knife"
    folder.mkdir()
    (folder / "test-00000.tar").write_bytes(b"")  # a folder of real meshes may hold one split only
    assert splits_with_shards(tmp_path, "knife", "all") == ["test"]
    assert shard_urls(tmp_path, "knife", "all") == [str(folder / "test-00000.tar")]
    every = shard_urls(shards, "knife", "all")
    assert every == sum((shard_urls(shards, "knife", n) for n in ("train", "val", "test")), [])
    with pytest.raises(ModelError, match="no val"):
        splits_with_shards(tmp_path, "knife", "val")
    with pytest.raises(ModelError, match="no category 'mug'"):
        splits_with_shards(tmp_path, "mug", "all")


def test_jitter_keeps_paper_white_and_flip_mirrors():
    img = np.full((32, 32), 255, np.uint8)
    img[10:20, 4:8] = 0
    rng = np.random.default_rng(0)
    out = jitter_image(img, rng, Jitter(max_rotation_deg=0, min_crop=1.0), flip=True)
    assert out[0, 0] == 255 and out[15, 32 - 6] == 0 and out[15, 5] == 255
    # no crop and no rotation (fit --min-crop 1.0 with the rotation off): the drawing as rendered
    still = Jitter(max_rotation_deg=0, min_crop=1.0)
    assert all(np.array_equal(jitter_image(img, np.random.default_rng(s), still, False), img) for s in range(5))
    moved = jitter_image(img, np.random.default_rng(1), Jitter(), flip=False)
    assert moved.shape == img.shape and not np.array_equal(moved, img) and moved.min() < 128
