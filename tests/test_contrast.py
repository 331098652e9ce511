"""The contrastive term: InfoNCE on codes, the loader's pair drawings, and a run that uses both."""

import csv
import dataclasses
import itertools
import math
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import write_fixture_shards  # noqa: E402

from pipeline.core.settings_io import SettingError
from train.augmentation import Jitter
from train.data import DataSettings, make_loader
from train.fit import FitSettings, fit, load_run
from train.key_queue import KeyQueue, MomentumKeys
from train.losses.contrast import info_nce, info_nce_keys
from train.losses.weights import LossWeights


@pytest.fixture(scope="module")
def shards(tmp_path_factory):
    return write_fixture_shards(tmp_path_factory.mktemp("ds"), n_points=800, size=32)


def test_info_nce_rewards_matching_pairs_and_pulls_them_together():
    g = torch.Generator().manual_seed(0)
    codes = torch.randn(6, 16, generator=g)
    near = codes + 0.05 * torch.randn(6, 16, generator=g)
    assert info_nce(codes, near).mean() < 0.1  # each finds its partner
    shuffled = near[torch.tensor([1, 2, 3, 4, 5, 0])]
    assert info_nce(codes, shuffled).mean() > 3.0  # partners are someone else's
    # a gradient step on the pair codes moves each towards its own partner
    far = torch.randn(6, 16, generator=g).requires_grad_(True)
    info_nce(codes, far).mean().backward()
    moved = far - 1.0 * far.grad
    cos = lambda x: torch.nn.functional.cosine_similarity(codes, x, dim=1)  # noqa: E731
    assert (cos(moved.detach()) > cos(far.detach())).all()
    assert info_nce(codes[:1], near[:1]).tolist() == [0.0]  # no negatives, no term
    with pytest.raises(ValueError):
        info_nce(codes, codes[:, :8])


def test_loader_pairs_each_sample_with_another_drawing_of_its_model(shards):
    # no image jitter: a pair that differs from its sample is another drawing, not a re-jittered copy
    still = Jitter(max_rotation_deg=0.0, min_crop=1.0)
    data = DataSettings(max_views=1, n_points=200, image_size=32, shuffle_buffer=4, pair=True, jitter=still)
    for batch in itertools.islice(make_loader(shards, "knife", "train", data, seed=2, batch_size=4), 3):
        pairs, firsts = batch["pair_images"], batch["images"][:, 0]
        assert pairs.shape == firsts.shape == (4, 1, 32, 32)
        assert all(not torch.equal(p, f) for p, f in zip(pairs, firsts))
    assert 0 < pairs.mean() < 0.5  # inked drawings on paper
    plain = next(
        iter(
            make_loader(
                shards,
                "knife",
                "train",
                DataSettings(max_views=1, n_points=200, image_size=32, shuffle_buffer=4),
                seed=2,
                batch_size=4,
            )
        )
    )
    assert "pair_images" not in plain


def test_a_run_with_the_contrastive_term_logs_it_and_rebuilds(shards, tmp_path):
    out = tmp_path / "contrast"
    base = dict(
        dataset=str(shards),
        category="knife",
        template="sphere24",
        out=str(out),
        steps=3,
        batch_size=3,
        workers=0,
        n_points=300,
        image_size=32,
        max_views=1,
        log_every=1,
        checkpoint_every=100,
        encoder_width=16,
        weights=LossWeights(collision=0.0),
    )
    fit(FitSettings(**base, contrast=0.5), progress=False)
    rows = list(csv.DictReader(open(out / "log.csv")))
    assert len(rows) == 3 and all(float(r["contrast"]) > 0 for r in rows)
    run = load_run(out / "checkpoint.pt")
    assert run.settings.contrast == 0.5 and run.step == 3
    # off by default: no pair drawings are loaded and the column stays empty
    fit(FitSettings(**{**base, "out": str(tmp_path / "plain")}), progress=False)
    assert {r["contrast"] for r in csv.DictReader(open(tmp_path / "plain" / "log.csv"))} == {""}


def test_momentum_keys_term_learns_only_through_the_query_and_masks_its_own_model():
    g = torch.Generator().manual_seed(1)
    codes = torch.randn(4, 8, generator=g).requires_grad_(True)
    keys = codes.detach() + 0.05 * torch.randn(4, 8, generator=g)
    ids = torch.tensor([10, 11, 12, 13])
    assert info_nce_keys(codes, keys, ids).mean() < 0.1
    shuffled = keys[torch.tensor([1, 2, 3, 0])]
    assert info_nce_keys(codes, shuffled, ids).mean() > 3.0
    # a model drawn twice in one batch is not its own negative: rows 0 and 1 share a model, and
    # their keys swapped still leave each anchor its own positive and no look-alike negative
    twice = torch.tensor([10, 10, 12, 13])
    swapped = keys[torch.tensor([1, 0, 2, 3])]
    assert info_nce_keys(codes, swapped, twice)[:2].max() > 3.0  # the positive is still row i's key
    assert info_nce_keys(codes, swapped, ids)[:2].min() > info_nce_keys(codes, swapped, twice)[:2].min()
    keys.requires_grad_(True)
    info_nce_keys(codes, keys, ids).mean().backward()
    assert codes.grad.abs().sum() > 0 and keys.grad is None  # keys are fixed targets


def test_queue_negatives_count_unless_masked_and_the_ring_wraps():
    g = torch.Generator().manual_seed(2)
    queue = KeyQueue(5, 8, torch.device("cpu"))
    codes = torch.randn(2, 8, generator=g)
    ids = torch.tensor([1, 2])
    assert not queue.negatives_mask(ids).any()  # empty slots are never negatives
    alone = info_nce_keys(codes, codes, ids, queue.keys, queue.negatives_mask(ids))
    # keys that look like the anchors, pushed as two other models and one of the anchors' own
    queue.push(torch.cat([codes, codes[:1]]), torch.tensor([7, 8, 1]))
    mask = queue.negatives_mask(ids)
    assert mask.tolist() == [[True, True, False, False, False], [True, True, True, False, False]]
    crowded = info_nce_keys(codes, codes, ids, queue.keys, mask)
    assert (crowded > alone + 0.5).all()  # look-alike negatives make the positive harder to pick
    # a masked entry does not count, whatever it holds
    queue.keys[2] = torch.nn.functional.normalize(codes[1], dim=0)
    assert torch.allclose(info_nce_keys(codes, codes, ids, queue.keys, queue.negatives_mask(ids))[0], crowded[0])
    queue.push(torch.randn(3, 8, generator=g), torch.tensor([20, 21, 22]))  # fills 3, 4 and wraps to 0
    assert queue.ids.tolist() == [22, 8, 1, 20, 21]
    assert torch.allclose(queue.keys.norm(dim=1), torch.ones(5))
    with pytest.raises(ValueError):
        info_nce_keys(codes, codes, ids, queue.keys)  # a queue needs its mask


def test_a_run_with_momentum_keys_fills_its_queue_and_needs_the_contrastive_term(shards, tmp_path):
    base = dict(
        dataset=str(shards),
        category="knife",
        template="sphere24",
        steps=4,
        batch_size=3,
        workers=0,
        n_points=300,
        image_size=32,
        max_views=1,
        log_every=1,
        checkpoint_every=100,
        encoder_width=16,
        contrast=0.5,
        weights=LossWeights(collision=0.0),
    )
    with pytest.raises(SettingError, match="momentum_queue"):
        FitSettings(**{**base, "contrast": 0.0}, out=str(tmp_path / "x"), momentum_queue=6)
    out = tmp_path / "moco"
    fit(FitSettings(**base, out=str(out), momentum_queue=6), progress=False)
    terms = [float(r["contrast"]) for r in csv.DictReader(open(out / "log.csv"))]
    # the first step has only the batch's 2 negatives; later steps add the queued keys (up to 6)
    assert len(terms) == 4 and terms[0] < math.log(3) + 0.7 < terms[-1]
    assert load_run(out / "checkpoint.pt").settings.momentum_queue == 6


def test_momentum_keys_follow_the_encoder_slowly_in_eval_mode():
    from train.resnet import ResNet18

    torch.manual_seed(0)
    live = ResNet18(1, 8)
    keys = MomentumKeys(live, None, momentum=0.9)
    images = torch.rand(4, 1, 32, 32)
    with torch.no_grad():
        first = keys.keys(images)
        assert torch.allclose(first, live.eval()(images))  # a copy at first, read in eval mode
        live.train()
        for p in live.parameters():
            p.add_(0.5)
    assert not any(p.requires_grad for p in keys.encoder.parameters())
    keys.update()  # 10 % of the way to the moved weights
    moved = dict(live.named_parameters())
    for name, p in keys.encoder.named_parameters():
        assert torch.allclose(p, moved[name] - 0.45, atol=1e-6)
    assert not torch.allclose(keys.keys(images), first)


def test_a_group_norm_run_saves_its_norm_and_loads_with_it(shards, tmp_path):
    out = tmp_path / "gn"
    settings = FitSettings(
        dataset=str(shards),
        category="knife",
        template="sphere24",
        out=str(out),
        steps=2,
        batch_size=3,
        workers=0,
        n_points=300,
        image_size=32,
        max_views=1,
        checkpoint_every=100,
        encoder_width=16,
        norm="group",
        weights=LossWeights(collision=0.0),
    )
    fit(settings, progress=False)
    run = load_run(out / "checkpoint.pt")
    assert run.settings.norm == "group"
    assert any(isinstance(m, torch.nn.GroupNorm) for m in run.model.modules())
    with pytest.raises(SettingError, match="norm"):
        FitSettings(**{**dataclasses.asdict(settings), "weights": settings.weights, "norm": "layer"})
