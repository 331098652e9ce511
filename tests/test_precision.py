"""The trainer's --precision: bf16 autocast on a GPU for the network alone, fp32 everywhere else."""

import dataclasses

import pytest
import torch

from pipeline.core.settings_io import SettingError
from train.fit import FitSettings, make_optimizer, train_step
from train.model import SketchToPatches, TrainingNet
from train.objective import Objective
from train.precision import network_autocast, place_network, reduced
from train.recipes import recipe
from train.templates import load_template

CUDA = torch.device("cuda")


def test_bf16_reduces_only_on_a_gpu():
    assert reduced(CUDA, "bf16")
    assert not reduced(torch.device("cpu"), "bf16")
    assert not reduced(CUDA, "fp32")
    with pytest.raises(ValueError, match="precision must be one of fp32, bf16, got 'fp16'"):
        reduced(CUDA, "fp16")


def test_the_setting_is_checked_and_named():
    with pytest.raises(SettingError, match=r"precision must be one of fp32, bf16, got 'fp16' \(--precision\)"):
        FitSettings(dataset="d", category="knife", template="knife", out="o", precision="fp16")


def _step_case(device: torch.device, precision: str, seed: int = 0) -> tuple:
    tpl = load_template("knife")
    torch.manual_seed(seed)
    model = SketchToPatches(tpl.initial_params(), encoder_width=8)
    torch.nn.init.normal_(model.out.weight, std=2e-3)  # outputs that depend on the drawing
    net = TrainingNet(place_network(model, device, precision))
    obj = Objective(tpl, 600)
    gen = torch.Generator().manual_seed(1)
    pts = torch.randn(4, 600, 6, generator=gen) * 0.3
    batch = {
        "images": torch.rand(4, 2, 1, 32, 32, generator=gen),
        "view_mask": torch.tensor([[True, True], [True, False], [True, True], [True, False]]),
        "points": pts,
        "meta": [{}] * 4,
    }
    st = obj.sample_st(torch.Generator().manual_seed(2))
    weights = recipe("knife").weights
    return net, make_optimizer(net, 1e-3, device), obj, batch, st, weights


def test_on_a_cpu_bf16_is_the_fp32_step():
    cpu = torch.device("cpu")
    runs = []
    for precision in ("fp32", "bf16"):
        net, opt, obj, batch, st, w = _step_case(cpu, precision)
        loss, terms = train_step(net, opt, obj, batch, st, w, cpu, precision=precision)
        runs.append((float(loss), [p.detach().clone() for p in net.parameters()]))
    assert runs[0][0] == runs[1][0]
    assert all(torch.equal(a, b) for a, b in zip(runs[0][1], runs[1][1]))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_on_a_gpu_bf16_keeps_the_loss_and_its_direction():
    """The network in bf16, channels-last; the loss it feeds within 1 % of fp32's, the gradient
    w.r.t. its outputs pointing the same way (the bench's check, BENCHMARKS.md)."""
    got = {}
    for precision in ("fp32", "bf16"):
        net, opt, obj, batch, st, w = _step_case(CUDA, precision)
        if precision == "bf16":
            conv = net.model.encoder.stem[0].weight
            assert conv.is_contiguous(memory_format=torch.channels_last)
        net.eval()
        with network_autocast(CUDA, precision):
            out = net(batch["images"].to(CUDA), batch["view_mask"])["params"]
        assert out.dtype == (torch.bfloat16 if precision == "bf16" else torch.float32)
        params = out.float().detach().requires_grad_(True)
        terms = obj.batch_terms(params, batch, st, dataclasses.replace(w, collision=0.0))
        loss = terms["chamfer"].mean() + terms["normal"].mean()
        (grad,) = torch.autograd.grad(loss, params)
        got[precision] = (float(loss), grad.flatten())
    assert abs(got["bf16"][0] - got["fp32"][0]) <= 0.01 * got["fp32"][0]
    assert float(torch.nn.functional.cosine_similarity(got["bf16"][1], got["fp32"][1], 0)) > 0.99
