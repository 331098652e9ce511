"""``--mirror-average``: the network's reading of a drawing averaged with its reading of the
drawing flipped left to right, mirrored back through the template's parameter mirror."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from train.augmentation import Jitter, jitter_image
from train.data import param_mirror
from train.errors import UsageError
from train.mirror_average import MirrorAverage
from train.model import SketchToPatches
from train.templates import load_template


@pytest.fixture(scope="module")
def airplane():
    template = load_template("airplane")
    torch.manual_seed(0)
    model = SketchToPatches(template.initial_params(), encoder_width=8).eval()
    with torch.no_grad():  # a fresh network answers with the (symmetric) template: give it a lean
        for weight in model.parameters():
            weight.add_(0.05 * torch.randn_like(weight))
    return template, model, param_mirror(template)


def _mirrored(params: torch.Tensor, mirror) -> torch.Tensor:
    return params[:, torch.as_tensor(mirror.perm)] * torch.as_tensor(mirror.sign)


def test_a_drawing_symmetric_left_to_right_gives_a_symmetric_shape(airplane) -> None:
    template, model, mirror = airplane
    half = torch.rand(2, 1, 1, 32, 16, generator=torch.Generator().manual_seed(1))
    images = torch.cat([half, torch.flip(half, dims=[-1])], dim=-1)  # each row reads the same both ways
    with torch.no_grad():
        plain = model(images)
        averaged = MirrorAverage(model, template)(images)
    # the network alone answers with an asymmetric shape; the average is its own mirror image
    assert (plain - _mirrored(plain, mirror)).abs().max() > 1e-3
    assert torch.allclose(averaged, _mirrored(averaged, mirror), atol=1e-5)


def test_it_flips_as_training_flips_and_mirrors_a_flipped_drawing(airplane) -> None:
    template, model, mirror = airplane
    img = np.full((32, 32), 255, np.uint8)
    img[4:28, 3:6] = 0  # a stroke near the left edge: the flip moves it to the right
    flat = Jitter(max_rotation_deg=0.0, min_crop=1.0)
    flipped = jitter_image(img, np.random.default_rng(0), flat, flip=True)
    assert flipped[10, 27] == 0 and flipped[10, 4] == 255
    seen: list[torch.Tensor] = []

    class Recorder(torch.nn.Module):
        def forward(self, images, view_mask=None):
            seen.append(images.clone())
            return model(images, view_mask)

    x = torch.from_numpy(img).float().div(255)[None, None, None]
    with torch.no_grad():
        out = MirrorAverage(Recorder(), template)(x)
        out_flipped = MirrorAverage(model, template)(torch.flip(x, dims=[-1]))
    assert torch.equal(seen[0][1, 0, 0], torch.from_numpy(flipped).float().div(255))
    # the flipped drawing shows the mirrored shape, and gets exactly the mirrored answer
    assert torch.allclose(out_flipped, _mirrored(out, mirror), atol=1e-5)


def test_a_template_that_does_not_mirror_is_refused_by_name(airplane) -> None:
    template, model, _ = airplane
    lopsided = dataclasses.replace(template, symmetry=None)
    with pytest.raises(UsageError, match="airplane.*mirror-average"):
        MirrorAverage(model, lopsided)
