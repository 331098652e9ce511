"""Coons patch geometry checked against independent computations."""

import numpy as np
import torch

from train.geometry import (
    bezier_derivative,
    bezier_eval,
    bezier_subdivide,
    blossom,
    coons_jacobian,
    coons_normals,
    coons_partials,
    coons_points,
    evaluate_patches,
    grid_params,
    grid_triangulation,
    patch_from_corners,
    sample_surface_uniform,
    triangulate_patches,
    uniform_params,
    welded_mesh,
)
from train.templates import sphere24

torch.set_num_threads(1)


def random_patches(gen: torch.Generator, n: int = 3) -> torch.Tensor:
    """Random curves whose end points chain around the patch (c_k end = c_{k+1} start)."""
    c = torch.randn(n, 4, 4, 3, generator=gen, dtype=torch.float64)
    for k in range(4):
        c[:, (k + 1) % 4, 0] = c[:, k, 3]
    return c


def numpy_bezier(ctrl: np.ndarray, t: np.ndarray) -> np.ndarray:
    b = np.stack([(1 - t) ** 3, 3 * t * (1 - t) ** 2, 3 * t**2 * (1 - t), t**3], -1)
    return b @ ctrl


def test_bezier_matches_paper_formula_and_derivative_matches_finite_difference():
    gen = torch.Generator().manual_seed(0)
    ctrl = torch.randn(5, 4, 3, generator=gen, dtype=torch.float64)
    t = torch.linspace(0, 1, 11, dtype=torch.float64)
    for i in range(5):
        np.testing.assert_allclose(
            bezier_eval(ctrl[i], t).numpy(), numpy_bezier(ctrl[i].numpy(), t.numpy()), atol=1e-12
        )
    h = 1e-6
    fd = (bezier_eval(ctrl, t + h) - bezier_eval(ctrl, t - h)) / (2 * h)
    torch.testing.assert_close(bezier_derivative(ctrl, t), fd, atol=1e-7, rtol=1e-7)


def test_subdivision_is_exact_and_blossom_is_diagonal_curve():
    gen = torch.Generator().manual_seed(1)
    ctrl = torch.randn(4, 4, 3, generator=gen, dtype=torch.float64)
    t = torch.rand(7, generator=gen, dtype=torch.float64)
    diag = blossom(ctrl[:, None], t, t, t)
    torch.testing.assert_close(diag, bezier_eval(ctrl, t))
    a, b = 0.2, 0.7
    sub = bezier_subdivide(ctrl, a, b)
    u = torch.linspace(0, 1, 9, dtype=torch.float64)
    torch.testing.assert_close(bezier_eval(sub, u), bezier_eval(ctrl, a + (b - a) * u))
    rev = bezier_subdivide(ctrl, b, a)  # reversed piece
    torch.testing.assert_close(bezier_eval(rev, u), bezier_eval(ctrl, b + (a - b) * u))


def test_corners_and_edges_reproduce_boundary_curves():
    p = random_patches(torch.Generator().manual_seed(2))
    u = torch.linspace(0, 1, 13, dtype=torch.float64)
    zeros, ones = torch.zeros_like(u), torch.ones_like(u)
    c1, c2, c3, c4 = (p[:, k] for k in range(4))
    torch.testing.assert_close(coons_points(p, torch.stack([u, zeros], -1)), bezier_eval(c1, u))
    torch.testing.assert_close(coons_points(p, torch.stack([ones, u], -1)), bezier_eval(c2, u))
    torch.testing.assert_close(coons_points(p, torch.stack([1 - u, ones], -1)), bezier_eval(c3, u))
    torch.testing.assert_close(coons_points(p, torch.stack([zeros, 1 - u], -1)), bezier_eval(c4, u))


def test_partials_match_finite_differences_and_normals_are_unit():
    p = random_patches(torch.Generator().manual_seed(3))
    st = uniform_params(3, 20, torch.Generator().manual_seed(4), dtype=torch.float64) * 0.9 + 0.05
    h = 1e-6
    ds = torch.tensor([h, 0.0], dtype=torch.float64)
    dt = torch.tensor([0.0, h], dtype=torch.float64)
    p_s, p_t = coons_partials(p, st)
    torch.testing.assert_close(
        p_s, (coons_points(p, st + ds) - coons_points(p, st - ds)) / (2 * h), atol=1e-7, rtol=1e-6
    )
    torch.testing.assert_close(
        p_t, (coons_points(p, st + dt) - coons_points(p, st - dt)) / (2 * h), atol=1e-7, rtol=1e-6
    )
    n = coons_normals(p, st)
    torch.testing.assert_close(n.norm(dim=-1), torch.ones(3, 20, dtype=torch.float64))
    torch.testing.assert_close(coons_jacobian(p, st), torch.linalg.cross(p_s, p_t, dim=-1).norm(dim=-1))


def test_jacobian_area_matches_fine_triangulation():
    p = sphere24().patches_from_params(sphere24().initial_params(torch.float64)[None])[0, :3]
    k = 200  # midpoint rule on a k×k grid of cell centres
    jac_area = coons_jacobian(p, grid_params(k, include_boundary=False, dtype=torch.float64)).mean(-1)
    verts, faces = triangulate_patches(p, 201)
    tri = verts[:, faces]
    tri_area = 0.5 * torch.linalg.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :], dim=-1).norm(
        dim=-1
    ).sum(-1)
    torch.testing.assert_close(jac_area, tri_area, rtol=1e-4, atol=0)


def test_grid_triangulation_is_ccw_and_oriented_with_normals():
    faces = grid_triangulation(4)
    assert faces.shape == (18, 3)
    st = grid_params(4, dtype=torch.float64)
    e1, e2 = st[faces[:, 1]] - st[faces[:, 0]], st[faces[:, 2]] - st[faces[:, 0]]
    assert torch.all(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0)
    flat = patch_from_corners(torch.tensor([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=torch.float64))
    assert torch.allclose(coons_normals(flat[None], st), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))


def test_coons_gradcheck_reaches_every_control_point():
    p = random_patches(torch.Generator().manual_seed(5), n=2).requires_grad_(True)
    st = torch.tensor([[0.3, 0.6], [0.8, 0.1], [0.5, 0.5]], dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda x: evaluate_patches(x, st).points, (p,))
    assert torch.autograd.gradcheck(lambda x: coons_jacobian(x, st), (p,))
    assert torch.autograd.gradcheck(lambda x: bezier_subdivide(x[0, 0], 0.25, 0.6), (p,))


def test_welded_sphere_mesh_is_closed():
    t = sphere24()
    v, f = welded_mesh(t.patches_from_params(t.initial_params(torch.float64)[None])[0], k=6)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)
    assert len(v) - len(edges) // 2 + len(f) == 2  # Euler characteristic of a sphere


def test_surface_samples_are_on_the_surface_and_deterministic():
    t = sphere24()
    p = t.patches_from_params(t.initial_params(torch.float64)[None])
    a, na = sample_surface_uniform(p, 2000, torch.Generator().manual_seed(7))
    b, _ = sample_surface_uniform(p, 2000, torch.Generator().manual_seed(7))
    assert torch.equal(a, b)
    assert a.shape == (1, 2000, 3)
    r = a.norm(dim=-1)
    assert r.min() > 0.98 and r.max() < 1.001
    assert ((na * a).sum(-1) > 0.95).all()  # outward normals
    # area-uniform: each octant holds ~1/8 of the points
    octant = ((a[0] > 0).long() * torch.tensor([1, 2, 4])).sum(-1)
    share = torch.bincount(octant, minlength=8).double() / 2000
    assert (share - 0.125).abs().max() < 0.03


def test_matrix_evaluation_equals_the_coons_formula_term_by_term():
    from train.geometry.coons import _partials_formula, _points_formula

    gen = torch.Generator().manual_seed(7)
    p = random_patches(gen, 4)[None].repeat(2, 1, 1, 1, 1)
    for st in (
        torch.rand(9, 2, generator=gen, dtype=torch.float64),
        torch.rand(4, 5, 2, generator=gen, dtype=torch.float64),
    ):
        ev = evaluate_patches(p, st)
        torch.testing.assert_close(ev.points, _points_formula(p, st), rtol=1e-12, atol=1e-12)
        p_s, p_t = _partials_formula(p, st)
        torch.testing.assert_close(coons_partials(p, st)[0], p_s, rtol=1e-12, atol=1e-12)
        cross = torch.linalg.cross(p_s, p_t, dim=-1)
        torch.testing.assert_close(ev.jacobian, cross.norm(dim=-1), rtol=1e-12, atol=1e-12)
        torch.testing.assert_close(coons_points(p, st), ev.points, rtol=1e-12, atol=1e-12)
