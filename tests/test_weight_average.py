"""The weight average (--ema): its update rule, and a run that validates, saves and resumes it."""

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import tiny_run, write_fixture_shards  # noqa: E402

from train.fit import FitSettings, fit, load_checkpoint, load_run
from train.weight_average import WeightAverage


def test_update_moves_floats_a_fraction_and_copies_counters():
    net = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.BatchNorm1d(4))
    avg = WeightAverage(net, 0.9)
    assert [avg.decay_at(s) for s in (0, 8, 80, 10_000)] == [0.1, 0.5, 0.9, 0.9]  # warms up to 0.9
    assert all(p.requires_grad is False for p in avg.model.parameters())
    before = {k: v.clone() for k, v in avg.model.state_dict().items()}
    with torch.no_grad():
        for p in net.parameters():
            p.add_(1.0)
    net.train()(torch.randn(5, 3))  # BatchNorm statistics and its step counter move
    avg.update(1000)
    now, live = avg.model.state_dict(), net.state_dict()
    for k, v in now.items():
        if v.is_floating_point():
            assert torch.allclose(v, 0.9 * before[k] + 0.1 * live[k], atol=1e-6), k
        else:
            assert torch.equal(v, live[k]), k  # num_batches_tracked
    assert not torch.equal(now["0.weight"], live["0.weight"])  # an average, not a copy
    with pytest.raises(ValueError):
        WeightAverage(net, 1.0)


@pytest.fixture(scope="module")
def shards(tmp_path_factory):
    return write_fixture_shards(tmp_path_factory.mktemp("ds"), n_points=800, size=32)


def test_a_run_hands_out_the_average_and_resumes_both(shards, tmp_path):
    out = tmp_path / "ema"
    base = tiny_run(shards, out, log_every=1, checkpoint_every=1, val_every=1, encoder_width=16, ema=0.2)
    fit(FitSettings(**base), progress=False)
    ck = load_checkpoint(out / "checkpoint.pt")
    served, trained = ck["model"], ck["train_model"]
    assert any(not torch.equal(served[k], trained[k]) for k in served)  # the average differs from training
    assert load_run(out / "checkpoint.pt").settings.ema == 0.2
    best = load_checkpoint(out / "best.pt")
    assert "train_model" in best and best["step"] in (1, 2)
    # a resume trains on from train_model and averages on from model (step 2's decay: min(0.2, 3/12))
    fit(FitSettings(**{**base, "steps": 3}), progress=False)
    ck3 = load_checkpoint(out / "checkpoint.pt")
    assert ck3["step"] == 3
    for k, v in ck3["model"].items():
        if v.is_floating_point():
            assert torch.allclose(v, 0.2 * served[k] + 0.8 * ck3["train_model"][k], atol=1e-6), k
    # off (the default): no separate training weights are stored
    fit(FitSettings(**{**base, "out": str(tmp_path / "plain"), "ema": 0.0, "steps": 1}), progress=False)
    assert "train_model" not in load_checkpoint(tmp_path / "plain" / "checkpoint.pt")
    with pytest.raises(ValueError, match="ema"):
        FitSettings(**{**base, "ema": 1.0, "steps": 1})
