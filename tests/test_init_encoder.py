"""`fit --init-encoder`: a run starts from another category's trained encoder and hidden layers."""

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import tiny_run, write_fixture_shards  # noqa: E402

from train.errors import UsageError
from train.fit import FitSettings, fit, load_checkpoint
from train.templates import load_template


@pytest.fixture(scope="module")
def shards(tmp_path_factory):
    return write_fixture_shards(tmp_path_factory.mktemp("ds"), n_points=800, size=32)


def _settings(shards: Path, out: Path, **kw) -> FitSettings:
    return FitSettings(**tiny_run(shards, out, **kw))


def test_a_run_starts_from_another_runs_encoder_with_its_own_output_layer(shards, tmp_path):
    torch.set_num_threads(1)
    fit(_settings(shards, tmp_path / "source", lr=1e-2), progress=False)
    source = load_checkpoint(tmp_path / "source" / "checkpoint.pt")["model"]
    # another template (another output size); a learning rate too small to move any weight
    fit(
        _settings(
            shards,
            tmp_path / "run",
            template="sphere54",
            steps=1,
            lr=1e-30,
            init_encoder=str(tmp_path / "source" / "checkpoint.pt"),
        ),
        progress=False,
    )
    run = load_checkpoint(tmp_path / "run" / "checkpoint.pt")
    started = run["model"]
    for key in ("encoder.stem.0.weight", "encoder.blocks.7.conv2.weight", "hidden.0.0.weight", "hidden.2.0.bias"):
        torch.testing.assert_close(started[key], source[key])
    torch.testing.assert_close(started["out.bias"], load_template("sphere54").initial_params().reshape(-1))
    assert started["out.weight"].abs().max() < 1e-20  # zero, as the paper starts it
    assert run["settings"]["init_encoder"].endswith("checkpoint.pt")
    # and without the option the same seed starts elsewhere
    fit(_settings(shards, tmp_path / "fresh", template="sphere54", steps=1, lr=1e-30), progress=False)
    fresh = load_checkpoint(tmp_path / "fresh" / "checkpoint.pt")["model"]
    assert not torch.allclose(fresh["encoder.stem.0.weight"], source["encoder.stem.0.weight"])


def test_an_encoder_of_another_width_is_refused_naming_the_file(shards, tmp_path):
    torch.set_num_threads(1)
    fit(_settings(shards, tmp_path / "source"), progress=False)
    path = tmp_path / "source" / "checkpoint.pt"
    with pytest.raises(UsageError, match=r"source/checkpoint\.pt: its network cannot start this one"):
        fit(_settings(shards, tmp_path / "run", encoder_width=16, init_encoder=str(path)), progress=False)


def test_a_checkpoint_without_network_weights_is_refused_naming_the_file(shards, tmp_path):
    path = tmp_path / "foreign.pt"
    torch.save({"settings": {}, "model": [1, 2, 3], "step": 0}, path)
    with pytest.raises(UsageError, match=r"foreign\.pt: not a sketch2patch checkpoint: its 'model' holds no network"):
        fit(_settings(shards, tmp_path / "run", init_encoder=str(path)), progress=False)
