"""The fit term (``--w-fit``): the loader hands out a ``--fit-patches`` build's fitted parameters
(mirrored with a flipped drawing, or marked invalid when the template cannot mirror them), the
term is the squared distance of predicted to fitted control points, its weight anneals over
``--fit-anneal-steps``, and ``python -m train fit`` trains with it on a tiny fitted build."""

from __future__ import annotations

import csv
import dataclasses
import io
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import webdataset as wds

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import write_fixture_shards  # noqa: E402
from test_patch_fit import CATEGORY, build  # noqa: E402

from pipeline.core import schema
from pipeline.dataset.shards import list_shards
from train.augmentation import Jitter
from train.data import DataSettings, ParamMirror, decode_sample, make_loader, param_mirror
from train.errors import UsageError
from train.fit import FitSettings, fit, step_weights
from train.losses.weights import LossWeights, only_term
from train.objective import Objective
from train.templates import load_template


@pytest.fixture(scope="module")
def fitted(tmp_path_factory) -> Path:
    """A tiny --fit-patches build: 3 procedural knives, 20 fit steps (test_patch_fit's settings)."""
    root = tmp_path_factory.mktemp("fitted")
    assert build(root)
    return root / "ds"


def _raw_samples(dataset: Path) -> list[dict]:
    urls = [str(p) for p in list_shards(dataset / CATEGORY)]
    return list(wds.WebDataset(urls, shardshuffle=False, empty_check=False))


def _stored_fit(raw: dict) -> np.ndarray:
    return np.load(io.BytesIO(raw[schema.FIT_PARAMS_MEMBER]))


# ---- the term ----------------------------------------------------------------------------------


def _fit_batch(fit_params: torch.Tensor, valid: list[bool]) -> dict:
    b = fit_params.shape[0]
    return {
        "points": torch.randn(b, 64, 6),
        "meta": [{}] * b,
        "key": [f"m{i}" for i in range(b)],
        "fit_params": fit_params,
        "fit_valid": torch.tensor(valid),
    }


def test_term_is_zero_at_the_fit_and_pulls_towards_it_elsewhere() -> None:
    tpl = load_template("sphere24")
    objective = Objective(tpl, n_points=64)
    st = objective.sample_st(None)
    target = tpl.initial_params()[None].repeat(3, 1) + 0.05 * torch.randn(3, tpl.num_params)
    weights = only_term("fit", LossWeights(fit=1.0))
    at_fit = objective.batch_terms(target.clone(), _fit_batch(target, [True] * 3), st, weights)["fit"]
    assert at_fit.shape == (3,) and torch.allclose(at_fit, torch.zeros(3), atol=1e-10)

    pred = (target + 0.1 * torch.randn_like(target)).requires_grad_(True)
    terms = objective.batch_terms(pred, _fit_batch(target, [True, False, True]), st, weights)
    expect = (tpl.points_from_params(pred) - tpl.points_from_params(target)).square().sum(-1).mean(-1)
    assert torch.allclose(terms["fit"][[0, 2]], expect[[0, 2]])
    assert terms["fit"][1] == 0  # an item without a valid fit target adds nothing
    terms["fit"].sum().backward()
    assert pred.grad is not None and pred.grad[0].abs().sum() > 0 and pred.grad[1].abs().sum() == 0
    # a step along the gradient comes closer to the fit
    closer = objective.batch_terms(pred.detach() - 0.1 * pred.grad, _fit_batch(target, [True] * 3), st, weights)
    assert closer["fit"][0] < terms["fit"][0]


def test_term_counts_only_present_patches_and_is_off_without_targets() -> None:
    tpl = load_template("airplane")
    objective = Objective(tpl, n_points=64)
    st = objective.sample_st(None)
    weights = only_term("fit", LossWeights(fit=1.0))
    base = tpl.initial_params()[None]
    labels = sorted(set(tpl.patch_labels))  # what a model's present_parts lists
    present = [p for p in labels if p != "engine"]
    unused = ~objective.used_points(objective.mask_for(present)[None])[0]  # the engines' own points
    assert unused.any()
    # move only those (free points; junctions keep their t): nothing of the engine-less model moves
    xyz = tpl.points_from_params(base.double())[0] + 0.3 * unused[:, None]
    pred = tpl.params_from_points(xyz.numpy()).float()[None]
    batch = {**_fit_batch(base, [True]), "meta": [{schema.PRESENT_PARTS: present}]}
    assert float(objective.batch_terms(pred, batch, st, weights)["fit"][0]) < 1e-10
    with_engines = {**batch, "meta": [{schema.PRESENT_PARTS: labels}]}
    assert float(objective.batch_terms(pred, with_engines, st, weights)["fit"][0]) > 1e-4
    # no fit targets in the batch: the term is skipped (reported as 0, no graph)
    plain = {k: v for k, v in batch.items() if not k.startswith("fit_")}
    assert float(objective.batch_terms(pred, plain, st, weights)["fit"][0]) == 0.0
    # a dataset fitted to another template is refused, naming the sample
    with pytest.raises(UsageError, match="m0: fitted parameters have 5 values"):
        objective.batch_terms(pred, _fit_batch(torch.zeros(1, 5), [True]), st, weights)


# ---- mirroring ---------------------------------------------------------------------------------


def test_mirrored_parameters_give_the_mirrored_shape() -> None:
    tpl = load_template("airplane")  # free points and junction points on mirrored curves
    mirror = param_mirror(tpl)
    assert mirror is not None and len(mirror.perm) == tpl.num_params
    p = tpl.initial_params(torch.float64) + 0.03 * torch.randn(tpl.num_params, dtype=torch.float64)
    q = torch.from_numpy(mirror(p.numpy()).astype(np.float64))
    a, b = tpl.points_from_params(p[None])[0], tpl.points_from_params(q[None])[0]
    for i, j in tpl.symmetry.pairs:
        for src, dst in ((i, j), (j, i)):
            assert torch.allclose(b[dst], a[src] * torch.tensor([-1.0, 1.0, 1.0], dtype=a.dtype), atol=1e-4)
    assert np.allclose(mirror(mirror(p.numpy())), p.numpy(), atol=1e-5)  # mirroring twice is the identity
    # no declared symmetry, a point left without a partner, or another plane than x = 0: no mirror
    assert param_mirror(load_template("knife")) is None
    partial = dataclasses.replace(tpl.symmetry, pairs=tpl.symmetry.pairs[1:])
    assert param_mirror(dataclasses.replace(tpl, symmetry=partial)) is None
    shifted = dataclasses.replace(tpl.symmetry, plane_x=0.2)
    assert param_mirror(dataclasses.replace(tpl, symmetry=shifted)) is None


def test_loader_returns_the_fits_and_handles_flipped_samples(fitted: Path) -> None:
    raws = _raw_samples(fitted)
    stored = {r["__key__"]: _stored_fit(r) for r in raws}
    data = DataSettings(max_views=1, n_points=200, image_size=64)
    batch = next(iter(make_loader(fitted, CATEGORY, "train", data, 0, 3, train=False)))
    assert batch["fit_params"].shape == (3, len(next(iter(stored.values()))))
    assert batch["fit_valid"].all()
    for key, row in zip(batch["key"], batch["fit_params"]):
        assert np.array_equal(row.numpy(), stored[key])

    flipping = dataclasses.replace(data, jitter=Jitter(flip=True))
    negate = ParamMirror(np.arange(len(row)), -np.ones(len(row), np.float32))
    seen = set()
    for seed in range(8):
        for raw in raws:
            plain = decode_sample(raw, flipping, np.random.default_rng(seed), True, True)
            mirrored = decode_sample(raw, flipping, np.random.default_rng(seed), True, True, negate)
            fit = stored[raw["__key__"]]
            flipped = not plain["fit_valid"]  # no mirror: a flipped sample's target is invalid
            assert mirrored["fit_valid"]
            assert np.array_equal(mirrored["fit_params"], -fit if flipped else fit)
            if not flipped:
                assert np.array_equal(plain["fit_params"], fit)
            seen.add(flipped)
    assert seen == {True, False}


# ---- the schedule and a run --------------------------------------------------------------------


def test_fit_weight_falls_linearly_to_zero() -> None:
    s = FitSettings(dataset="d", category="c", template="t", out="o", weights=LossWeights(fit=2.0))
    annealed = dataclasses.replace(s, fit_anneal_steps=100)
    assert [step_weights(annealed, k).fit for k in (0, 50, 100, 150)] == [2.0, 1.0, 0.0, 0.0]
    assert step_weights(annealed, 50).chamfer == s.weights.chamfer  # the other weights stay
    assert [step_weights(s, k).fit for k in (0, 100)] == [2.0, 2.0]  # 0: constant
    with pytest.raises(Exception, match="fit_anneal_steps"):
        FitSettings(dataset="d", category="c", template="t", out="o", fit_anneal_steps=-1)


def test_fit_with_the_fit_term_runs_on_a_fitted_build(fitted: Path, tmp_path: Path) -> None:
    from train.cli import main

    out = tmp_path / "run"
    argv = ["fit", "--dataset", str(fitted), "--category", CATEGORY, "--template", CATEGORY, "--out", str(out)]
    small = ["--steps", "6", "--batch-size", "2", "--points", "300", "--image-size", "64", "--encoder-width", "8"]
    assert main([*argv, *small, "--workers", "0", "--log-every", "1", "--w-fit", "1", "--fit-anneal-steps", "5"]) == 0
    rows = list(csv.DictReader(open(out / "log.csv")))
    assert len(rows) == 6 and all(np.isfinite(float(r["loss"])) for r in rows)
    assert float(rows[0]["fit"]) > 0  # the term is on at the start ...
    assert float(rows[-1]["fit"]) == 0  # ... and off once its weight has fallen to 0 (step 6 > 5)


@pytest.mark.parametrize(
    "option, flag",
    [({"weights": LossWeights(fit=1.0)}, "--w-fit"), ({"fit_readout": 1.0}, "--fit-readout")],
)
def test_fit_options_refuse_a_dataset_without_fits(tmp_path: Path, option: dict, flag: str) -> None:
    shards = write_fixture_shards(tmp_path / "ds", counts={"train": 4, "val": 2, "test": 2})
    s = FitSettings(
        dataset=str(shards),
        category="knife",
        template="sphere24",
        out=str(tmp_path / "run"),
        steps=2,
        batch_size=2,
        workers=0,
        n_points=200,
        image_size=64,
        encoder_width=8,
        **option,
    )
    with pytest.raises(UsageError, match=f"{flag} needs fitted patches.*--fit-patches, or give {flag} 0"):
        fit(s, progress=False)


# ---- the readout (--fit-readout) ---------------------------------------------------------------


def test_readout_teaches_the_encoder_and_never_the_output_layer() -> None:
    from train.fit import make_optimizer, train_step
    from train.model import SketchToPatches, TrainingNet

    tpl = load_template("sphere24")
    torch.manual_seed(0)
    model = SketchToPatches(tpl.initial_params(), hidden=(32,), encoder_width=8)
    net = TrainingNet(model, tpl.initial_params())
    images = torch.rand(3, 1, 1, 32, 32)
    out = net(images)
    assert torch.equal(out["readout"], out["params"])  # both start at the template
    assert len(list(net.parameters())) == len(list(model.parameters())) + 2  # the model's, then its own

    objective = Objective(tpl, n_points=64)
    target = tpl.initial_params()[None].repeat(3, 1) + 0.05 * torch.randn(3, tpl.num_params)
    batch = {**_fit_batch(target, [True] * 3), "images": images, "view_mask": torch.ones(3, 1, dtype=torch.bool)}
    readout = objective.readout_term(out["readout"], batch)
    expect = (tpl.points_from_params(out["readout"]) - tpl.points_from_params(target)).square().sum(-1).mean(-1)
    assert torch.allclose(readout, expect)
    assert objective.readout_term(out["readout"], {k: v for k, v in batch.items() if k != "fit_params"}) is None

    # only the readout's term: the encoder and the readout learn, the head's layers get nothing
    opt = make_optimizer(net, 1e-3, torch.device("cpu"))
    no_terms = dataclasses.replace(only_term("chamfer", LossWeights()), chamfer=0.0)
    first = None
    for _ in range(3):  # the readout starts at zero weights: the encoder's gradient comes from step 2
        net.zero_grad()
        loss, terms = train_step(
            net, opt, objective, batch, objective.sample_st(None), no_terms, torch.device("cpu"), fit_readout=1.0
        )
        first = float(terms["fit_readout"].detach().mean()) if first is None else first
        assert model.out.weight.grad is None or model.out.weight.grad.abs().sum() == 0
        assert all(p.grad is None or p.grad.abs().sum() == 0 for p in model.hidden.parameters())
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in model.encoder.parameters())
    with torch.no_grad():
        after = float(objective.readout_term(net(images)["readout"], batch).mean())
    assert after < first  # it learns the fits


def test_fit_with_the_readout_runs_and_resumes_on_a_fitted_build(fitted: Path, tmp_path: Path) -> None:
    from train.cli import main
    from train.fit import load_checkpoint

    out = tmp_path / "run"
    argv = ["fit", "--dataset", str(fitted), "--category", CATEGORY, "--template", CATEGORY, "--out", str(out)]
    small = ["--batch-size", "2", "--points", "300", "--image-size", "64", "--encoder-width", "8", "--workers", "0"]
    run = [*argv, *small, "--log-every", "1", "--checkpoint-every", "3", "--fit-readout", "2"]
    assert main([*run, "--steps", "3"]) == 0
    kept = load_checkpoint(out / "checkpoint.pt")
    assert set(kept["fit_readout"]) == {"weight", "bias"}  # a resume continues the readout too
    assert main([*run, "--steps", "5"]) == 0
    rows = list(csv.DictReader(open(out / "log.csv")))
    assert [int(r["step"]) for r in rows] == [1, 2, 3, 4, 5]
    assert all(float(r["fit_readout"]) > 0 for r in rows) and all(float(r["fit"]) == 0 for r in rows)


def test_readout_trains_under_two_rank_ddp(fitted: Path, tmp_path: Path) -> None:
    """Every rank builds the same readout and DDP sees it used each step: the ranks end with the
    same weights and only rank 0 writes the checkpoint, which holds the readout."""
    import json

    from test_ddp_fit import _spawn_within

    from train.fit import load_checkpoint

    out, report = tmp_path / "run", tmp_path / "report"
    report.mkdir()
    over = dict(template=CATEGORY, image_size=64, encoder_width=8, max_views=1, fit_readout=2.0)
    _spawn_within(300, str(fitted), str(out), str(report), over)
    r0, r1 = (json.loads((report / f"rank{r}.json").read_text()) for r in range(2))
    assert "error" not in r0 and "error" not in r1, (r0, r1)
    assert r0["param_digest"] == r1["param_digest"] and r0["last_loss"] == r1["last_loss"]
    assert set(load_checkpoint(out / "checkpoint.pt")["fit_readout"]) == {"weight", "bias"}
