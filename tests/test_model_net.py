import torch

from train.model import SketchToPatches
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
