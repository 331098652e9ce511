import pytest
import torch

from train.model import SketchToPatches, TrainingNet
from train.resnet import ResNet18


def test_resnet18_shape_and_size():
    net = ResNet18(1)
    assert net(torch.rand(2, 1, 64, 64)).shape == (2, 512)
    n = sum(p.numel() for p in net.parameters())
    assert 11.0e6 < n < 11.3e6  # ResNet-18 minus the 1000-way classifier, 1 input channel


def test_untrained_model_outputs_template_and_pools_views():
    init = torch.linspace(-1, 1, 30)
    m = SketchToPatches(init).eval()
    x = torch.rand(3, 2, 1, 32, 32)
    assert torch.equal(m(x), init.expand(3, 30))
    with torch.no_grad():
        m.out.weight.normal_()
    mask = torch.tensor([[True, False]] * 3)
    # a masked view is ignored: same as feeding only the first view
    assert torch.allclose(m(x, mask), m(x[:, :1]), atol=1e-5)
    assert not torch.allclose(m(x), m(x[:, :1]))
    assert torch.allclose(m.decode_latent(m.latent(x)), m(x))


def test_encoder_width_scales_every_stage_and_the_code():
    net = ResNet18(1, width=32)
    assert net(torch.rand(2, 1, 64, 64)).shape == (2, 256)
    n = sum(p.numel() for p in net.parameters())
    assert 2.7e6 < n < 2.9e6  # about a quarter of ResNet-18: weights grow with channels squared
    m = SketchToPatches(torch.linspace(-1, 1, 30), encoder_width=32).eval()
    assert m.encode(torch.rand(3, 2, 1, 32, 32)).shape == (3, 256)
    assert torch.equal(m(torch.rand(3, 1, 1, 32, 32)), torch.linspace(-1, 1, 30).expand(3, 30))  # still the template
    with pytest.raises(ValueError, match="encoder width"):
        ResNet18(1, width=0)


def test_padding_views_skip_the_encoder_and_its_batch_statistics():
    torch.manual_seed(0)
    m = SketchToPatches(torch.linspace(-1, 1, 30), encoder_width=8).train()
    with torch.no_grad():
        m.out.weight.normal_()
    x = torch.rand(4, 3, 1, 32, 32)
    mask = torch.tensor([[True, False, False], [True, True, False], [True, True, True], [True, False, True]])
    calls = []
    m.encoder.register_forward_hook(lambda mod, inp, out: calls.append(inp[0].shape[0]))
    out = m(x, mask)
    assert calls == [int(mask.sum())]  # 8 present views encoded, not 12
    # in training mode what a padding view holds changes nothing, batch-norm statistics included
    y = x.clone()
    y[~mask] = 1.0
    assert torch.allclose(m(y, mask), out, atol=1e-6)
    out.sum().backward()  # gradients reach the encoder through the present views
    assert m.encoder.stem[0].weight.grad.abs().sum() > 0


def test_training_net_returns_the_networks_parameters_and_the_pair_codes():
    m = SketchToPatches(torch.linspace(-1, 1, 30), encoder_width=16).eval()
    with torch.no_grad():
        m.out.weight.normal_()
    t = TrainingNet(m)
    assert [id(p) for p in t.parameters()] == [id(p) for p in m.parameters()]  # one optimizer state fits both
    x, pair = torch.rand(3, 2, 1, 32, 32), torch.rand(3, 1, 32, 32)
    plain = t(x)
    assert set(plain) == {"params"} and torch.equal(plain["params"], m(x))
    out = t(x, None, pair)
    assert torch.equal(out["params"], m(x))
    assert torch.equal(out["codes"], m.encode(x)) and torch.equal(out["pair_codes"], m.encode(pair))


def test_input_blur_feeds_the_drawing_and_two_ink_fields():
    from train.model import InkFields

    x = torch.zeros(1, 1, 64, 64)
    x[..., 30:32, :] = 1.0  # a horizontal line two pixels thick
    f = InkFields(2.0)(x)
    assert f.shape == (1, 3, 64, 64) and torch.equal(f[:, :1], x)
    # each field keeps about the line's darkness (2 px x 1) on the line and reaches off it
    assert f[0, 1, 31, 32] == pytest.approx(2.0, rel=0.1) and f[0, 2, 31, 32] == pytest.approx(2.0, rel=0.1)
    assert f[0, 1, 36, 32] > 0.01 and f[0, 1, 45, 32] < 1e-3 < f[0, 2, 45, 32]
    m = SketchToPatches(torch.linspace(-1, 1, 30), encoder_width=8, input_blur=2.0).eval()
    assert m.encoder.stem[0].in_channels == 3
    assert torch.equal(m(torch.rand(2, 1, 1, 32, 32)), torch.linspace(-1, 1, 30).expand(2, 30))


def test_page_coordinates_tell_the_encoder_where_the_ink_lies():
    from train.model import PageCoordinates

    x = torch.zeros(2, 1, 5, 7)
    f = PageCoordinates()(x)
    assert f.shape == (2, 3, 5, 7) and torch.equal(f[:, :1], x)
    assert torch.allclose(f[0, 1, 0], torch.linspace(-1, 1, 7)) and torch.allclose(
        f[0, 2, :, 0], torch.linspace(-1, 1, 5)
    )
    m = SketchToPatches(torch.linspace(-1, 1, 30), encoder_width=8, page_coordinates=True, input_blur=2.0).eval()
    assert m.encoder.stem[0].in_channels == 5  # the drawing, two ink fields, x and y
    assert m.fields(torch.zeros(1, 1, 16, 16))[0, 3:].abs().amax() == 1.0
    assert torch.equal(m(torch.rand(2, 1, 1, 32, 32)), torch.linspace(-1, 1, 30).expand(2, 30))


def test_a_pooling_grid_keeps_each_cell_of_the_page_apart():
    from train.resnet import ResNet18

    torch.manual_seed(0)
    enc = ResNet18(1, 8, grid=2).eval()
    assert enc.out_features == 256
    x = torch.rand(1, 1, 64, 64)
    cells = enc.blocks(enc.stem(x))  # (1, 64, 2, 2) at 64²
    assert torch.allclose(enc(x), cells.flatten(1), atol=1e-6)
    one = ResNet18(1, 8).eval()
    one.load_state_dict(enc.state_dict())
    # the global code is the mean of the four cells' codes
    assert torch.allclose(one(x), enc(x).view(1, 64, 4).mean(-1), atol=1e-6)
