"""The output layer's shape basis: principal directions of fits, the readout, a run that uses it."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import tiny_run, write_fixture_shards  # noqa: E402

from pipeline.core.fit_settings import PatchFitSettings
from train.fit import FitSettings, fit, load_checkpoint, load_run
from train.model import BasisReadout, SketchToPatches
from train.shape_basis import fitted_shapes, principal_basis
from train.templates import load_template


def test_principal_basis_recovers_the_spread_of_the_shapes():
    rng = np.random.default_rng(0)
    d = 12
    axes = np.linalg.qr(rng.normal(size=(d, 2)))[0].T  # two orthonormal directions
    coeffs = rng.normal(size=(400, 2)) * np.array([3.0, 0.5])
    params = 1.0 + coeffs @ axes + rng.normal(scale=1e-4, size=(400, d))
    basis = principal_basis(params, variance=0.99)
    assert basis.directions.shape == (2, d)
    assert basis.explained > 0.99
    lengths = np.linalg.norm(basis.directions, axis=1)  # one standard deviation each
    assert lengths == pytest.approx([3.0, 0.5], rel=0.1)
    # the directions span the generating ones
    unit = basis.directions / lengths[:, None]
    assert np.abs(unit @ axes.T).max(axis=1) == pytest.approx([1.0, 1.0], abs=1e-3)
    # deterministic signs: the same fits, negated about their mean, give the same basis
    again = principal_basis(2 * params.mean(0) - params, variance=0.99)
    np.testing.assert_allclose(again.directions, basis.directions, atol=1e-5)


def test_principal_basis_refuses_what_has_no_spread():
    with pytest.raises(ValueError, match="at least 2"):
        principal_basis(np.ones((1, 5)))
    with pytest.raises(ValueError, match="all the same"):
        principal_basis(np.ones((4, 5)))


def test_basis_readout_starts_at_the_template_and_moves_along_the_basis():
    torch.manual_seed(0)
    init = torch.linspace(-1, 1, 30)
    basis = torch.randn(3, 30)
    model = SketchToPatches(init, encoder_width=8, basis=basis).eval()
    images = torch.rand(2, 1, 1, 32, 32)
    with torch.no_grad():
        torch.testing.assert_close(model(images), init.expand(2, -1))
        model.out.weight.normal_()
        moved = model(images) - init
    # every prediction lies in the template + span(basis)
    coeffs = torch.linalg.lstsq(basis.T, moved.T).solution
    torch.testing.assert_close(coeffs.T @ basis, moved, atol=1e-4, rtol=1e-4)
    with pytest.raises(ValueError, match="basis must be"):
        BasisReadout(16, torch.randn(3, 29), init)


@pytest.fixture(scope="module")
def shards(tmp_path_factory):
    return write_fixture_shards(tmp_path_factory.mktemp("ds"), n_points=800, size=32)


def test_fits_of_training_models_differ_by_model(shards):
    torch.set_num_threads(1)
    tpl = load_template("sphere24")
    fits = fitted_shapes(str(shards), "knife", tpl, shapes=3, settings=PatchFitSettings(steps=20, points=300))
    assert fits.shape == (3, tpl.num_params)
    start = tpl.initial_params().numpy()
    assert np.abs(fits - start).max() > 1e-3  # fitted, not the template
    assert np.abs(fits[0] - fits[1]).max() > 1e-4  # each to its own model


def test_a_run_with_a_shape_basis_trains_resumes_and_loads(shards, tmp_path):
    torch.set_num_threads(1)
    out = tmp_path / "run"
    s = FitSettings(**tiny_run(shards, out, shape_basis=4))
    first = fit(s, progress=False)
    summary = json.loads((out / "shape_basis.json").read_text())
    assert summary["shapes"] == 4 and 1 <= summary["directions"] <= 3
    basis = load_checkpoint(out / "checkpoint.pt")["model"]["out.basis"]
    assert basis.shape == (summary["directions"], load_template("sphere24").num_params)
    second = fit(FitSettings(**{**s.__dict__, "steps": 3}), progress=False)  # resumes with the saved basis
    assert second["param_digest"] != first["param_digest"]
    run = load_run(out / "checkpoint.pt")
    assert isinstance(run.model.out, BasisReadout)
    torch.testing.assert_close(run.model.out.basis, basis)
