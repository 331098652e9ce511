"""The shape-code term: distance descriptors, their whitened basis, and a run that trains and resumes with it."""

import csv
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import write_fixture_shards  # noqa: E402

from train.fit import FitSettings, fit, load_checkpoint, load_run, training_shape_basis
from train.losses.shape_code import anchor_grid, distance_descriptor, fit_basis, shape_code_loss
from train.losses.weights import LossWeights


@pytest.fixture(scope="module")
def shards(tmp_path_factory):
    return write_fixture_shards(tmp_path_factory.mktemp("ds"), n_points=800, size=32)


def test_descriptor_is_the_distance_to_the_nearest_point():
    anchors = anchor_grid(4)
    assert anchors.shape == (64, 3) and float(anchors.abs().max()) == 0.75
    pts = torch.tensor([[[0.75, 0.75, 0.75, 0, 0, 1], [-0.75, -0.75, -0.75, 0, 0, 1]]])
    d = distance_descriptor(pts, anchors)
    assert d.shape == (1, 64)
    assert float(d[0, 0]) == 0.0 and float(d[0, -1]) == 0.0  # the two corner anchors lie on a point
    assert torch.allclose(d[0, 1], torch.tensor(0.5))  # (-0.75, -0.75, -0.25): 0.5 from a corner


def test_basis_whitens_the_training_shapes_and_tells_them_apart():
    g = torch.Generator().manual_seed(0)
    anchors = anchor_grid(4)
    # point clouds filling boxes of random proportions: three degrees of freedom, three components
    sizes = 0.2 + 0.6 * torch.rand(40, 1, 3, generator=g)
    shapes = (2 * torch.rand(40, 2000, 3, generator=g) - 1) * sizes
    basis = fit_basis(distance_descriptor(shapes, anchors), anchors, dims=3)
    c = basis.coefficients(shapes)
    assert c.shape == (40, 3)
    assert torch.allclose(c.mean(0), torch.zeros(3), atol=1e-4)
    assert torch.allclose(c.std(0), torch.ones(3), atol=1e-3)
    # the same basis again from the same descriptors (sign convention), and its state round-trips
    again = fit_basis(distance_descriptor(shapes, anchors), anchors, dims=3)
    assert torch.equal(again.components, basis.components)
    assert torch.equal(type(basis).from_state(basis.state()).coefficients(shapes), c)
    # a wider box lands far from a narrow one; two samplings of one box land close
    resampled = (2 * torch.rand(40, 2000, 3, generator=g) - 1) * sizes
    same = (basis.coefficients(resampled) - c).norm(dim=1).median()
    other = (c[torch.randperm(40, generator=g)] - c).norm(dim=1).median()
    assert other > 3 * same
    # the loss is the mean squared coefficient error per item
    assert torch.allclose(shape_code_loss(c, torch.zeros_like(c)), c.pow(2).mean(1))
    with pytest.raises(ValueError):
        fit_basis(torch.zeros(1, 64), anchors)


def test_a_run_with_the_shape_code_logs_it_saves_its_basis_and_resumes(shards, tmp_path):
    out = tmp_path / "shape"
    base = dict(dataset=str(shards), category="knife", template="sphere24", out=str(out), steps=3, batch_size=3,
                workers=0, n_points=300, image_size=32, max_views=1, log_every=1, checkpoint_every=1,
                encoder_width=16, weights=LossWeights(collision=0.0), shape_code=0.5)  # fmt: skip
    fit(FitSettings(**base), progress=False)
    rows = list(csv.DictReader(open(out / "log.csv")))
    assert len(rows) == 3 and all(float(r["shape_code"]) > 0 for r in rows)
    ckpt = load_checkpoint(out / "checkpoint.pt")
    basis = ckpt["training"]["shape_basis"]
    expected = training_shape_basis(FitSettings(**base))
    assert torch.equal(basis["components"], expected.components)
    head = ckpt["training"]["shape_head"]
    assert head["weight"].shape == (expected.dims, 16 * 8)
    # resuming trains the saved head on: its weights move on, the network still loads for use
    fit(FitSettings(**{**base, "steps": 5}), progress=False)
    later = load_checkpoint(out / "checkpoint.pt")
    assert later["step"] == 5 and not torch.equal(later["training"]["shape_head"]["weight"], head["weight"])
    assert load_run(out / "checkpoint.pt").settings.shape_code == 0.5
    # off by default: no head, no basis, the column stays empty
    fit(FitSettings(**{**base, "shape_code": 0.0, "out": str(tmp_path / "plain")}), progress=False)
    assert "training" not in load_checkpoint(tmp_path / "plain" / "checkpoint.pt")
    assert {r["shape_code"] for r in csv.DictReader(open(tmp_path / "plain" / "log.csv"))} == {""}
