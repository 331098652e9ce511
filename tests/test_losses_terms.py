"""The paper's loss terms against independent computations."""

import numpy as np
import pytest
import torch

from train.geometry import evaluate_patches, grid_params, patch_from_corners, sample_surface_uniform, uniform_params
from train.geometry.intersections import count_intersecting_pairs
from train.geometry.patch_pairs import collision_pairs, unconnected_pairs
from train.losses import (
    LossWeights,
    chamfer_loss,
    collision_loss,
    flatness_loss,
    match_points,
    normal_alignment_loss,
    symmetry_loss,
    template_normal_loss,
    total_loss,
)
from train.nn_search import nearest_distances
from train.objective import Objective
from train.templates import sphere24, sphere54
from train.templates.template import Curve, FreePoint, Patch, Template

torch.set_num_threads(1)


def sphere_patches(t, dtype=torch.float64):
    return t.patches_from_params(t.initial_params(dtype)[None])


def test_nearest_distances_equal_dense_cdist_values_and_gradients():
    gen = torch.Generator().manual_seed(0)
    q = torch.randn(2, 300, 3, generator=gen, dtype=torch.float64, requires_grad=True)
    r = torch.randn(2, 200, 3, generator=gen, dtype=torch.float64, requires_grad=True)
    d, _ = nearest_distances(q, r)
    dense = torch.cdist(q, r).min(-1).values
    torch.testing.assert_close(d, dense)
    g1 = torch.autograd.grad(d.sum(), (q, r))
    g2 = torch.autograd.grad(dense.sum(), (q, r))
    for a, b in zip(g1, g2):
        torch.testing.assert_close(a, b)


def test_chamfer_is_near_zero_on_itself_and_grows_with_offset():
    t = sphere54()
    p = sphere_patches(t)
    target, normals = sample_surface_uniform(p, 20000, torch.Generator().manual_seed(1))
    st = uniform_params(t.num_patches, 400, torch.Generator().manual_seed(2), dtype=torch.float64)
    ev = evaluate_patches(p, st)
    base = chamfer_loss(ev.points, ev.jacobian, target)
    assert base.item() < 0.03  # the sampling floor: ~half the sample spacing each way
    for delta in (0.1, 0.2):
        shifted = target + delta * normals  # the surface moved outward by delta
        value = chamfer_loss(ev.points, ev.jacobian, shifted)
        assert abs(value.item() - 2 * delta) < 0.02  # ≈ delta each way


def test_chamfer_weights_patch_side_by_jacobian():
    # one large and one small flat patch, target far away: patch side = area-weighted mean height
    corners = torch.tensor(
        [[[0, 0, 1], [2, 0, 1], [2, 2, 1], [0, 2, 1]], [[5, 0, 3], [6, 0, 3], [6, 1, 3], [5, 1, 3]]],
        dtype=torch.float64,
    )
    p = patch_from_corners(corners)[None]
    ev = evaluate_patches(p, grid_params(5, dtype=torch.float64))
    target = torch.tensor([[[1.0, 1.0, 0.0], [5.5, 0.5, 0.0]]], dtype=torch.float64)
    m = match_points(ev.points, target)
    patch_side = (chamfer_loss(ev.points, ev.jacobian, target, matches=m) - 0).item()
    d = torch.cdist(ev.points.reshape(1, -1, 3), target).min(-1).values.reshape(2, -1)
    expected = (4 * d[0].mean() + 1 * d[1].mean()) / 5 + torch.cdist(target, ev.points.reshape(1, -1, 3)).min(
        -1
    ).values.mean()
    assert patch_side == pytest.approx(expected.item(), rel=1e-9)


def test_chamfer_gradcheck_float64():
    corners = torch.tensor([[[0, 0, 0], [1, 0, 0.2], [1, 1, 0], [0, 1, 0.1]]], dtype=torch.float64)
    p = patch_from_corners(corners)[None].clone().requires_grad_(True)
    target = torch.rand(1, 30, 3, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    st = torch.rand(10, 2, generator=torch.Generator().manual_seed(4), dtype=torch.float64)

    def f(x):
        ev = evaluate_patches(x, st)
        return chamfer_loss(ev.points, ev.jacobian, target)

    assert torch.autograd.gradcheck(f, (p,))


def test_normal_alignment_zero_for_matching_and_eight_for_flipped():
    t = sphere24()
    p = sphere_patches(t)
    ev = evaluate_patches(p, grid_params(6, include_boundary=False, dtype=torch.float64))
    target = ev.points.reshape(1, -1, 3)
    m = match_points(ev.points, target)
    same = normal_alignment_loss(ev.normals, ev.jacobian, ev.normals.reshape(1, -1, 3), m)
    flipped = normal_alignment_loss(ev.normals, ev.jacobian, -ev.normals.reshape(1, -1, 3), m)
    assert same.item() < 1e-12
    assert flipped.item() == pytest.approx(8.0)


def test_flatness_zero_for_planar_affine_patch_and_positive_for_sphere():
    flat = patch_from_corners(torch.tensor([[0, 0, 0], [2, 0, 1], [2, 1, 1], [0, 1, 0]], dtype=torch.float64))[
        None, None
    ]
    st = grid_params(6, dtype=torch.float64)
    ev = evaluate_patches(flat, st)
    assert flatness_loss(ev.points, st, ev.jacobian).item() < 1e-20
    twisted = patch_from_corners(torch.tensor([[0, 0, 0], [1, 0, 0], [1, 1, 1], [0, 1, 0]], dtype=torch.float64))[
        None, None
    ]
    ev = evaluate_patches(twisted, st)
    # residual of a bilinear z = s·t after the best affine fit, independently with numpy lstsq
    s, t_ = st[:, 0].numpy(), st[:, 1].numpy()
    X = np.stack([s, t_, np.ones_like(s)], 1)
    P = ev.points[0, 0].numpy()
    res = ((X @ np.linalg.lstsq(X, P, rcond=None)[0] - P) ** 2).sum(1)
    w = ev.jacobian[0, 0].numpy()
    assert flatness_loss(ev.points, st, ev.jacobian).item() == pytest.approx((res * w).sum() / w.sum(), rel=1e-9)
    sp = sphere_patches(sphere24())
    ev = evaluate_patches(sp, st)
    assert flatness_loss(ev.points, st, ev.jacobian).item() > 1e-5


def test_template_normal_and_symmetry_terms():
    t = sphere24()
    prm = t.initial_params(torch.float64)[None]
    st = grid_params(4, dtype=torch.float64)
    ev = evaluate_patches(t.patches_from_params(prm), st)
    assert template_normal_loss(ev.normals, ev.normals[0], ev.jacobian).item() < 1e-20
    assert template_normal_loss(-ev.normals, ev.normals[0], ev.jacobian).item() == pytest.approx(4.0)
    pairs = t.symmetry_pairs()
    assert symmetry_loss(t.points_from_params(prm), pairs).item() < 1e-20
    moved = prm.clone()
    i = t.symmetry.pairs[0][0]
    moved[0, t._offsets[i] + 1] += 0.1  # move one paired point up by 0.1
    expected = 0.01 / len(pairs)
    assert symmetry_loss(t.points_from_params(moved), pairs).item() == pytest.approx(expected)
    # a shifted plane sees the sphere as asymmetric
    assert symmetry_loss(t.points_from_params(prm), pairs, plane_x=0.5).item() > 0.1


def _square(z0, x0=0.0):
    """Corners of a unit square in the plane z = z0 (x from x0), paper order."""
    return torch.tensor([[x0, 0, z0], [x0 + 1, 0, z0], [x0 + 1, 1, z0], [x0, 1, z0]], dtype=torch.float64)


def _wall(x, z_lo, z_hi):
    """Corners of a vertical unit-wide patch in the plane x = const spanning z_lo..z_hi."""
    return torch.tensor([[x, 0, z_lo], [x, 1, z_lo], [x, 1, z_hi], [x, 0, z_hi]], dtype=torch.float64)


def test_collision_zero_for_template_and_for_apart_patches():
    t = sphere24()
    assert collision_loss(sphere_patches(t), collision_pairs(t, grid=8)).item() == 0.0
    apart = patch_from_corners(torch.stack([_square(0.0), _wall(3.37, -0.3, 0.7)]))[None]
    assert collision_loss(apart, unconnected_pairs(2, grid=8)).item() == 0.0


def test_collision_sees_a_crossing_between_grid_vertices_and_its_gradient_separates():
    # the wall crosses the square mid-cell (x = 0.37 is no grid column of an 8-grid, z = 0 no row
    # of the wall's grid): the paper's vertex-to-triangle indicator gives 0 here
    loose = unconnected_pairs(2, grid=8)
    corners = torch.stack([_square(0.0), _wall(0.37, -0.3, 0.7)])
    patches = patch_from_corners(corners)[None].requires_grad_(True)
    loss = collision_loss(patches, loose)
    assert loss.item() > 0.05
    (grad,) = torch.autograd.grad(loss.sum(), patches)
    # descent lifts the wall (most of it is above the square) and lowers the square under it
    assert -grad[0, 1, ..., 2].sum() > 0 and -grad[0, 0, ..., 2].sum() < 0
    # plain gradient descent on this term alone ends the crossing
    x = patches.detach().clone().requires_grad_(True)
    for _ in range(200):
        l = collision_loss(x, loose).sum()
        if l.item() == 0.0:
            break
        (g,) = torch.autograd.grad(l, x)
        with torch.no_grad():
            x -= 0.05 * g
    assert collision_loss(x, loose).item() == 0.0
    assert count_intersecting_pairs(x[0].detach()) == 0
    assert count_intersecting_pairs(patches[0].detach()) == 1


def test_collision_zero_for_patches_that_only_share_an_edge():
    # two patches of a template folded at 90 degrees along their shared curve: touching, not crossing
    pts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (0, 1, 1)]
    t = _two_patch_template(pts)
    pairs = collision_pairs(t, grid=8)
    patches = t.patches_from_params(t.initial_params(torch.float64)[None])
    assert pairs.pairs.tolist() == [[0, 1]] and not pairs.keep_i.all()  # adjacent: truncated
    assert collision_loss(patches, pairs).item() == 0.0
    # flat continuation (180 degrees) touches along the same edge: also 0
    t2 = _two_patch_template([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (-1, 0, 0), (-1, 1, 0)])
    assert (
        collision_loss(
            t2.patches_from_params(t2.initial_params(torch.float64)[None]), collision_pairs(t2, grid=8)
        ).item()
        == 0.0
    )


def _two_patch_template(pts) -> Template:
    """Patches (0,1,2,3) and (0,3,5,4) sharing the curve 3→0 (straight cubic curves)."""
    points = [FreePoint(tuple(float(v) for v in p)) for p in pts]
    curves = []

    def curve(a, b):
        pa, pb = np.array(pts[a], float), np.array(pts[b], float)
        points.extend(FreePoint(tuple(pa + (pb - pa) * f)) for f in (1 / 3, 2 / 3))
        curves.append(Curve(points=(a, len(points) - 2, len(points) - 1, b)))
        return len(curves) - 1

    c01, c12, c23, c30 = curve(0, 1), curve(1, 2), curve(2, 3), curve(3, 0)
    c04, c45, c53 = curve(0, 4), curve(4, 5), curve(5, 3)
    patches = [Patch((c01, c12, c23, c30)), Patch((c04, c45, c53, c30))]
    return Template(points=points, curves=curves, patches=patches)


def test_total_loss_reaches_every_parameter_and_ablation_switches_terms_off():
    t = sphere24()
    prm = t.initial_params(torch.float64)[None].repeat(2, 1)
    prm = (
        prm + 0.01 * torch.randn(prm.shape, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    ).requires_grad_(True)
    target, normals = sample_surface_uniform(sphere_patches(t) * 1.1, 3000, torch.Generator().manual_seed(6))
    target, normals = target.repeat(2, 1, 1), normals.repeat(2, 1, 1)
    st = uniform_params(t.num_patches, 64, torch.Generator().manual_seed(7), dtype=torch.float64)
    template_normals = evaluate_patches(sphere_patches(t), st).normals[0]
    kwargs = dict(
        template_normals=template_normals,
        control_points=t.points_from_params(prm),
        symmetry_pairs=t.symmetry_pairs(),
        collision=collision_pairs(t),
    )
    loss, terms = total_loss(t.patches_from_params(prm), st, target, normals, LossWeights(), **kwargs)
    assert set(terms) == {"chamfer", "normal", "flat", "collision", "template_normal", "symmetry", "fit", "fold"}
    assert terms["fit"].item() == 0.0  # off by default (and without fit targets)
    assert terms["fold"].item() == 0.0  # off by default
    assert all(terms[k].item() > 0 for k in ("chamfer", "normal", "flat", "template_normal", "symmetry"))
    weights = LossWeights()
    expected = sum(getattr(weights, k) * v for k, v in terms.items())
    assert loss.item() == pytest.approx(expected.item())
    (grad,) = torch.autograd.grad(loss, prm)
    assert (grad.abs() > 0).all()  # every control point of every patch gets a gradient
    no_flat, terms2 = total_loss(
        t.patches_from_params(prm), st, target, normals, LossWeights(flat=0.0, symmetry=0.0), **kwargs
    )
    assert terms2["flat"].item() == 0.0 and terms2["symmetry"].item() == 0.0
    assert no_flat.item() == pytest.approx(loss.item() - 2.0 * terms["flat"].item() - terms["symmetry"].item())


def test_patch_mask_removes_absent_parts():
    t = sphere24()
    p = sphere_patches(t)
    st = grid_params(5, include_boundary=False, dtype=torch.float64)
    ev = evaluate_patches(p, st)
    keep = torch.zeros(1, t.num_patches, dtype=torch.bool)
    keep[0, :12] = True
    target = ev.points[:, :12].reshape(1, -1, 3)  # target = only the kept half
    _, with_mask = total_loss(p, st, target, ev.normals[:, :12].reshape(1, -1, 3), patch_mask=keep)
    _, without = total_loss(p, st, target, ev.normals[:, :12].reshape(1, -1, 3))
    assert with_mask["chamfer"].item() < 1e-9 < without["chamfer"].item()


def _folding_square(inner_x: tuple[float, float] = (1 / 3, 2 / 3), lift: float = 0.0) -> torch.Tensor:
    """The unit square as one Coons patch (1, 1, 4, 4, 3), its bottom and top curves' inner
    control points at x = ``inner_x`` (running back past each other: the patch folds) and
    z = ``lift``."""
    corners = torch.tensor([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=torch.float64)
    p = patch_from_corners(corners).clone()
    p[0, 1:3, 0] = torch.tensor(inner_x, dtype=torch.float64)  # bottom, P00 -> P10
    p[2, 1:3, 0] = torch.tensor(inner_x[::-1], dtype=torch.float64)  # top, P11 -> P01
    p[0, 1:3, 2] = p[2, 1:3, 2] = lift
    return p[None, None]


def test_fold_sees_a_patch_folded_over_itself_and_its_gradient_unfolds_it():
    from train.losses.regularizers import fold_loss

    st = uniform_params(1, 400, torch.Generator().manual_seed(1), dtype=torch.float64)
    flat = evaluate_patches(_folding_square(), st)
    template_normals = flat.normals[0]
    assert fold_loss(flat.normals, flat.jacobian, template_normals).item() == 0.0
    x = _folding_square((1.2, -0.2), lift=0.2)  # x(s) runs back in the middle of a curved patch
    first = None
    for _ in range(30):
        x.requires_grad_(True)
        ev = evaluate_patches(x, st)
        loss = fold_loss(ev.normals, ev.jacobian, template_normals)
        first = loss.item() if first is None else first
        (grad,) = torch.autograd.grad(loss, x)
        x = (x - 0.05 * grad).detach()
    ev = evaluate_patches(x, st)
    assert first > 0.1  # a fifth of the patch turned over
    assert fold_loss(ev.normals, ev.jacobian, template_normals).item() < 0.01  # descent unfolds it


def test_collision_without_truncation_keeps_the_seam_band_and_still_ignores_the_shared_edge():
    pts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (0, 1, 1)]  # folded at 90 degrees
    t = _two_patch_template(pts)
    full = collision_pairs(t, grid=8, truncate=0)
    # only the two shared corner vertices are left out; training's default leaves out a row
    assert int((~full.keep_i).sum()) == int((~full.keep_j).sum()) == 2
    assert int((~Objective(t, 200, collision_truncate=0).pairs.keep_i).sum()) == 2
    assert int((~Objective(t, 200).pairs.keep_i).sum()) > 8
    # the grids share their vertices along the common curve: touching there is not crossing
    patches = t.patches_from_params(t.initial_params(torch.float64)[None])
    assert collision_loss(patches, full).item() == 0.0


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_nearest_search_on_cuda_matches_cpu():
    gen = torch.Generator().manual_seed(9)
    q = torch.randn(2, 5000, 3, generator=gen)
    r = torch.randn(2, 4000, 3, generator=gen)
    d_cpu, _ = nearest_distances(q, r)
    d_gpu, _ = nearest_distances(q.cuda(), r.cuda())
    torch.testing.assert_close(d_gpu.cpu(), d_cpu, atol=1e-5, rtol=1e-5)


def test_regularizer_gradcheck_float64():
    gen = torch.Generator().manual_seed(11)
    corners = torch.tensor([[[0, 0, 0], [1, 0, 0.3], [1, 1, 0], [0, 1, 0.2]]], dtype=torch.float64)
    p = patch_from_corners(corners)[None] + 0.05 * torch.randn(1, 1, 4, 4, 3, generator=gen, dtype=torch.float64)
    for k in range(4):  # keep the loop of curves closed
        p[:, :, (k + 1) % 4, 0] = p[:, :, k, 3]
    p.requires_grad_(True)
    st = torch.rand(8, 2, generator=gen, dtype=torch.float64)
    tn = torch.nn.functional.normalize(torch.randn(1, 8, 3, generator=gen, dtype=torch.float64), dim=-1)
    target = torch.rand(1, 12, 3, generator=gen, dtype=torch.float64)
    target_n = torch.nn.functional.normalize(torch.randn(1, 12, 3, generator=gen, dtype=torch.float64), dim=-1)

    def f(x):
        ev = evaluate_patches(x, st)
        m = match_points(ev.points, target)
        return torch.stack(
            [
                flatness_loss(ev.points, st, ev.jacobian),
                template_normal_loss(ev.normals, tn, ev.jacobian),
                normal_alignment_loss(ev.normals, ev.jacobian, target_n, m),
                symmetry_loss(x.reshape(1, -1, 3), torch.tensor([[0, 5], [3, 3]]), plane_x=0.1),
            ]
        )

    assert torch.autograd.gradcheck(f, (p,))


def test_collision_skips_absent_patches():
    crossing = patch_from_corners(torch.stack([_square(0.0), _wall(0.37, -0.3, 0.7)]))[None].repeat(2, 1, 1, 1, 1)
    mask = torch.tensor([[True, True], [True, False]])
    out = collision_loss(crossing, unconnected_pairs(2, grid=8), patch_mask=mask)
    assert out[0] > 0 and out[1] == 0


def _thin_wall(n: int = 400):
    """Target: a wall of thickness 0.04 (top at z=+0.02 facing +z, bottom at z=−0.02 facing −z);
    patch samples facing +z just below the middle, i.e. nearer the bottom face."""
    gen = torch.Generator().manual_seed(3)
    xy = torch.rand(n, 2, generator=gen, dtype=torch.float64) - 0.5
    top = torch.cat([xy, torch.full((n, 1), 0.02, dtype=torch.float64)], 1)
    bottom = torch.cat([xy, torch.full((n, 1), -0.02, dtype=torch.float64)], 1)
    target = torch.cat([top, bottom])[None]
    normals = torch.cat([torch.tensor([[0, 0, 1.0]]).expand(n, 3), torch.tensor([[0, 0, -1.0]]).expand(n, 3)])
    normals = normals.double()[None]
    g = torch.linspace(-0.3, 0.3, 10, dtype=torch.float64)
    xx, yy = torch.meshgrid(g, g, indexing="ij")
    pts = torch.stack([xx, yy, torch.full_like(xx, -0.01)], -1).reshape(1, 1, -1, 3).requires_grad_(True)
    pn = torch.tensor([0, 0, 1.0], dtype=torch.float64).expand(pts.shape)
    return pts, pn, target, normals


def test_normal_aware_matching_keeps_partners_on_the_facing_side_of_a_thin_wall():
    pts, pn, target, normals = _thin_wall()
    jac = torch.ones(pts.shape[:3], dtype=torch.float64)
    plain = match_points(pts, target)
    aware = match_points(pts, target, normals=(pn, normals), normal_weight=0.1)
    # plain: the nearer (bottom, facing away) face; aware: the top face, which faces the same way
    assert (normals[0, plain.patch_to_target[0], 2] < 0).all()
    assert (normals[0, aware.patch_to_target[0], 2] > 0).all()
    flat_pts = pts.reshape(1, -1, 3)

    def patch_side_z_grad(m):  # gradient of the patch → target half of L_Ch
        d = (flat_pts - target[0, m.patch_to_target[0]][None]).norm(dim=-1).mean()
        return torch.autograd.grad(d, pts)[0][..., 2]

    # descending the plain loss pushes the upward-facing patch down through the wall, the aware one up
    assert (patch_side_z_grad(plain) > 0).all() and (patch_side_z_grad(aware) < 0).all()
    assert torch.isfinite(chamfer_loss(pts, jac, target, matches=aware)).all()
    # the aware normal term sees agreeing normals; the plain one pairs opposite ones (‖n − n'‖² = 4)
    flat = pn.reshape(1, 1, -1, 3)
    assert (
        normal_alignment_loss(flat, jac, normals, aware).item()
        < normal_alignment_loss(flat, jac, normals, plain).item()
    )
    with pytest.raises(ValueError):
        match_points(pts, target, normal_weight=0.1)


def test_objective_uses_normal_aware_matching_in_training_only():
    from train.objective import Objective

    t = sphere24()
    obj = Objective(t, n_points=600, match_normals=0.5)
    gen = torch.Generator().manual_seed(1)
    params = t.initial_params()[None] + 0.05 * torch.randn(1, t.initial_params().numel(), generator=gen)
    pts = torch.randn(1, 600, 3, generator=gen)
    pts = pts / pts.norm(dim=-1, keepdim=True)
    batch = {"points": torch.cat([pts, -pts], -1), "meta": [{}]}  # normals pointing inwards: aware ≠ plain
    w = LossWeights(normal=0.0, flat=0.0, collision=0.0)
    st = obj.sample_st(None)
    train_aware = obj.batch_terms(params, batch, st, w)["chamfer"]
    metric = obj.batch_terms(params, batch, st, w, training=False)["chamfer"]
    plain = Objective(t, n_points=600).batch_terms(params, batch, st, w)["chamfer"]
    torch.testing.assert_close(metric, plain)
    assert train_aware.item() > plain.item() + 1e-3
