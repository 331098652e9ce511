"""Evaluation metrics against brute-force numpy computations and known configurations."""

import numpy as np
import pytest
import torch

from train.geometry import patch_from_corners, sample_surface_uniform
from train.geometry.intersections import count_intersecting_pairs, triangles_intersect
from train.geometry.patch_pairs import collision_pairs, unconnected_pairs
from train.metrics import chamfer_l2_x1000, chamfer_loss_style, fscore, normal_consistency, relative_change_interval
from train.templates import sphere24, sphere54

torch.set_num_threads(1)


def test_chamfer_l2_x1000_matches_brute_force():
    gen = torch.Generator().manual_seed(0)
    a = torch.rand(2, 500, 3, generator=gen, dtype=torch.float64)
    b = torch.rand(2, 400, 3, generator=gen, dtype=torch.float64)
    d = ((a.numpy()[:, :, None] - b.numpy()[:, None]) ** 2).sum(-1)
    expected = 1000 * (d.min(2).mean(1) + d.min(1).mean(1))
    np.testing.assert_allclose(chamfer_l2_x1000(a, b).numpy(), expected, rtol=1e-12)
    np.testing.assert_allclose(chamfer_l2_x1000(a, b, average_directions=True).numpy(), expected / 2, rtol=1e-12)


def test_fscore_and_normal_consistency_on_known_offsets():
    gen = torch.Generator().manual_seed(1)
    a = torch.rand(1, 300, 3, generator=gen, dtype=torch.float64) * 10
    shifted = a + torch.tensor([0.015, 0, 0], dtype=torch.float64)
    assert fscore(a, shifted, 0.02).item() == pytest.approx(1.0)
    assert fscore(a, shifted, 0.01).item() == pytest.approx(0.0)
    half = torch.cat([a[:, :150], a[:, 150:] + 5.0], 1)  # half the prediction far away
    assert 0.4 < fscore(half, a, 0.01).item() < 0.6
    n = torch.nn.functional.normalize(torch.randn(1, 300, 3, generator=gen, dtype=torch.float64), dim=-1)
    assert normal_consistency(a, n, a, n).item() == pytest.approx(1.0)
    assert normal_consistency(a, n, a, -n).item() == pytest.approx(1.0)  # unoriented
    perp = torch.linalg.cross(
        n, torch.nn.functional.normalize(torch.randn(1, 300, 3, generator=gen, dtype=torch.float64), dim=-1), dim=-1
    )
    assert normal_consistency(a, n, a, torch.nn.functional.normalize(perp, dim=-1)).item() < 1e-9


def test_chamfer_loss_style_small_on_own_surface():
    t = sphere54()
    p = t.patches_from_params(t.initial_params(torch.float64)[None])
    target, _ = sample_surface_uniform(p, 20000, torch.Generator().manual_seed(2))
    own = chamfer_loss_style(p, target, torch.Generator().manual_seed(3), num_points=20000).item()
    bigger = chamfer_loss_style(p * 1.2, target, torch.Generator().manual_seed(3), num_points=20000).item()
    assert own < 0.03 and bigger > 0.35


def test_triangle_intersection_cases():
    t1 = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=float)
    piercing = np.array([[[0.2, 0.2, -1], [0.2, 0.2, 1], [0.3, 0.25, 1]]], dtype=float)
    above = piercing + np.array([0, 0, 2.5])
    assert triangles_intersect(t1, piercing).tolist() == [True]
    assert triangles_intersect(t1, above).tolist() == [False]


def test_count_intersecting_pairs():
    t = sphere24()
    p = t.patches_from_params(t.initial_params(torch.float64)[None])[0]
    assert count_intersecting_pairs(p, collision_pairs(t)) == 0
    # a +x patch moved across to the -x side, half inside and half outside, crosses patches there
    pushed = p.clone()
    pushed[0] = pushed[0] - torch.tensor([1.6, 0.0, 0.0], dtype=torch.float64)
    assert count_intersecting_pairs(pushed, collision_pairs(t)) > 0
    horizontal = torch.tensor([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=torch.float64)
    vertical = torch.tensor([[0.5, 0, -0.5], [0.5, 1, -0.5], [0.5, 1, 0.5], [0.5, 0, 0.5]], dtype=torch.float64)
    crossing = patch_from_corners(torch.stack([horizontal, vertical, vertical + 5.0]))
    assert count_intersecting_pairs(crossing, unconnected_pairs(3)) == 1
    assert count_intersecting_pairs(crossing, unconnected_pairs(3), torch.tensor([True, False, True])) == 0


def test_relative_change_interval_is_the_ratio_of_means_with_a_seeded_bootstrap_around_it():
    gen = torch.Generator().manual_seed(0)
    base = 0.08 + 0.02 * torch.rand(400, generator=gen)
    values = base * (0.75 + 0.2 * torch.randn(400, generator=gen))  # 25 % below, shape by shape noisy
    r = relative_change_interval(values[:100], base[:100])
    assert r["change"] == pytest.approx(float(values[:100].mean() / base[:100].mean() - 1))
    assert r["low"] < r["change"] < r["high"] and r["level"] == 0.95
    assert r == relative_change_interval(values[:100], base[:100])  # seeded: the same figures each call
    wide = r["high"] - r["low"]
    # four times the shapes, about half the width (1/sqrt(n))
    r4 = relative_change_interval(values, base)
    assert 0.35 * wide < r4["high"] - r4["low"] < 0.7 * wide
    # a paired resample: a network exactly as good as its baseline on every shape has no width
    same = relative_change_interval(base, base)
    assert same["change"] == 0 and same["low"] == pytest.approx(0) and same["high"] == pytest.approx(0)
    with pytest.raises(ValueError, match="equal"):
        relative_change_interval(values, base[:10])
