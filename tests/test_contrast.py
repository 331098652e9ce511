"""The contrastive term: InfoNCE on codes, the loader's pair drawings, and a run that uses both."""

import csv
import itertools
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import tiny_run, write_fixture_shards  # noqa: E402

from train.augmentation import Jitter
from train.data import DataSettings, make_loader
from train.fit import FitSettings, fit, load_run
from train.losses.contrast import info_nce


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
    base = tiny_run(shards, out, steps=3, batch_size=3, log_every=1, checkpoint_every=100, encoder_width=16)
    fit(FitSettings(**base, contrast=0.5), progress=False)
    rows = list(csv.DictReader(open(out / "log.csv")))
    assert len(rows) == 3 and all(float(r["contrast"]) > 0 for r in rows)
    run = load_run(out / "checkpoint.pt")
    assert run.settings.contrast == 0.5 and run.step == 3
    # off by default: no pair drawings are loaded and the column stays empty
    fit(FitSettings(**{**base, "out": str(tmp_path / "plain")}), progress=False)
    assert {r["contrast"] for r in csv.DictReader(open(tmp_path / "plain" / "log.csv"))} == {""}


def test_a_run_with_the_pair_loss_alone_loads_the_pairs_and_learns_from_them(shards, tmp_path):
    """``--pair-loss`` without the contrastive term: the loader still draws the pairs, and the
    pair's drawings change what the run learns (against a run that draws the same pairs for a
    contrastive term too small to move a weight)."""
    torch.set_num_threads(1)
    base = tiny_run(shards, tmp_path, batch_size=3)
    del base["out"]
    paired = fit(FitSettings(**base, out=str(tmp_path / "paired"), pair_loss=1.0), progress=False)
    plain = fit(FitSettings(**base, out=str(tmp_path / "plain"), contrast=1e-30), progress=False)
    again = fit(FitSettings(**base, out=str(tmp_path / "again"), contrast=1e-30), progress=False)
    assert plain["param_digest"] == again["param_digest"]  # the comparison is exact
    assert load_run(tmp_path / "paired" / "checkpoint.pt").settings.pair_loss == 1.0
    assert paired["param_digest"] != plain["param_digest"]
    assert {r["contrast"] for r in csv.DictReader(open(tmp_path / "paired" / "log.csv"))} == {""}
