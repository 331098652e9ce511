import numpy as np
import torch
from test_export_bicubic import random_patches

from train.export.bicubic import coons_to_bezier
from train.export.iges import eval_surface, iges_text, read_iges, write_iges
from train.export.units import CadUnits
from train.geometry.coons import coons_points


def test_iges_roundtrip_matches_coons_patches(tmp_path):
    patches = random_patches(4, seed=3) * 10.0
    path = tmp_path / "p.igs"
    write_iges(path, coons_to_bezier(patches), CadUnits("mm", 1.0))  # file numbers = model coordinates
    lines = path.read_text().splitlines()
    assert all(len(line) == 80 for line in lines)
    assert [line[72] for line in lines][0] == "S" and lines[-1][72] == "T"
    assert "".join(dict.fromkeys(line[72] for line in lines)) == "SGDPT"
    surfaces = read_iges(path)
    assert len(surfaces) == 4
    st = np.random.default_rng(0).uniform(size=(300, 2))
    want = coons_points(torch.from_numpy(patches), torch.from_numpy(st)).numpy()
    for k, surf in enumerate(surfaces):
        got = eval_surface(surf, st[:, 0], st[:, 1])
        assert np.abs(got - want[k]).max() < 1e-6


def test_iges_is_deterministic():
    nets = coons_to_bezier(random_patches(2))
    assert iges_text(nets) == iges_text(nets)
