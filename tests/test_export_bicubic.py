import numpy as np
import torch

from train.export.bicubic import coons_to_bezier, eval_bezier_surface
from train.geometry.coons import coons_points


def random_patches(n: int, seed: int = 0) -> np.ndarray:
    """Patches with shared corners but arbitrary curved boundaries."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 4, 4, 3))
    # close the loop: c1 end = c2 start, c2 end = c3 start, c3 end = c4 start, c4 end = c1 start
    p[:, 1, 0] = p[:, 0, 3]
    p[:, 2, 0] = p[:, 1, 3]
    p[:, 3, 0] = p[:, 2, 3]
    p[:, 3, 3] = p[:, 0, 0]
    return p


def test_bezier_net_reproduces_coons_exactly():
    patches = random_patches(5)
    nets = coons_to_bezier(patches)
    st = np.random.default_rng(1).uniform(size=(200, 2))
    want = coons_points(torch.from_numpy(patches), torch.from_numpy(st)).numpy()
    got = np.stack([eval_bezier_surface(n, st[:, 0], st[:, 1]) for n in nets])
    assert np.abs(got - want).max() < 1e-12
    # boundary rows of the net are the boundary curves' control points
    assert np.allclose(nets[:, :, 0], patches[:, 0])
    assert np.allclose(nets[:, 3, :], patches[:, 1])
