"""Exact nearest neighbours: the hashed grid (train.grid_nn) against scipy's k-d tree."""

import shutil
import warnings

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

import train.nn_search as nn_search
from train.grid_nn import grid_nearest
from train.losses import LossWeights
from train.nn_search import nearest_distances, nearest_indices
from train.objective import Objective
from train.templates import load_template

torch.set_num_threads(1)
RNG = np.random.default_rng(0)


def kdtree(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    return np.stack([cKDTree(r[b]).query(q[b], k=1)[1] for b in range(q.shape[0])])


def sq_dist(q: np.ndarray, r: np.ndarray, idx: np.ndarray) -> np.ndarray:
    return ((q - np.take_along_axis(r, idx[..., None], 1)) ** 2).sum(-1)


def surface(n: int, b: int = 2) -> np.ndarray:
    p = RNG.normal(size=(b, n, 3))
    return p / np.linalg.norm(p, axis=-1, keepdims=True)


CLOUDS = {
    "uniform": lambda: (RNG.random((2, 700, 3)), RNG.random((2, 500, 3))),
    "clustered": lambda: (
        RNG.normal(size=(2, 900, 3)) * 0.01 + RNG.integers(0, 4, (2, 900, 1)),
        RNG.normal(size=(2, 600, 3)) * 0.01 + RNG.integers(0, 4, (2, 600, 1)),
    ),
    "surface with noise": lambda: (surface(3000) + 0.02 * RNG.normal(size=(2, 3000, 3)), surface(2500)),
    "many queries, few references": lambda: (RNG.normal(size=(2, 4000, 3)), RNG.normal(size=(2, 7, 3))),
    "few queries, many references": lambda: (RNG.normal(size=(2, 3, 3)), RNG.normal(size=(2, 5000, 3))),
    "one reference point": lambda: (RNG.normal(size=(1, 200, 3)), RNG.normal(size=(1, 1, 3))),
    "one query point": lambda: (RNG.normal(size=(1, 1, 3)), RNG.normal(size=(1, 300, 3))),
    "queries far outside": lambda: (RNG.random((2, 300, 3)) * 50 + 40, surface(800)),
    "references far outside": lambda: (surface(600), np.concatenate([surface(500), RNG.random((2, 50, 3)) + 1e6], 1)),
    "flat (a plane)": lambda: (RNG.random((2, 500, 3)) * [1, 1, 0.1], RNG.random((2, 400, 3)) * [1, 1, 0]),
}


@pytest.mark.parametrize("name", CLOUDS)
def test_grid_equals_kdtree(name: str) -> None:
    q, r = CLOUDS[name]()
    got, want = grid_nearest(q, r), kdtree(q, r)
    assert got.shape == q.shape[:2] and got.dtype == np.int64
    # float64 random clouds have no exact ties, so the indices themselves must agree
    np.testing.assert_array_equal(got, want)


def test_coincident_reference_points_go_to_the_lowest_index() -> None:
    base = surface(400, b=1)
    r = np.concatenate([base, base[:, ::-1], base], 1)  # every point three times
    for q in (
        base + 1e-3 * RNG.normal(size=base.shape),  # near: answered by the grid
        RNG.random((1, 50, 3)) * 40 + 30,
    ):  # far: past the grid's budget, the k-d tree answers
        got = grid_nearest(q, r)
        np.testing.assert_array_equal(sq_dist(q, r, got), sq_dist(q, r, kdtree(q, r)))
        # base[i] lies at i, 799 - i and 800 + i: the answer is always the first copy
        np.testing.assert_array_equal(got[0], ((q[0][:, None] - base[0][None]) ** 2).sum(-1).argmin(1))


def test_many_copies_of_one_point_and_queries_on_reference_points() -> None:
    r = np.concatenate([np.full((1, 300, 3), 0.25), RNG.random((1, 300, 3))], 1)
    q = np.concatenate([r[:, 250:350], RNG.random((1, 100, 3))], 1)
    got = grid_nearest(q, r)
    np.testing.assert_array_equal(sq_dist(q, r, got), sq_dist(q, r, kdtree(q, r)))
    assert (got[0, :50] == 0).all() and (got[0, 50:100] == np.arange(300, 350)).all()


def test_grid_declines_what_it_cannot_hash() -> None:
    assert grid_nearest(np.zeros((1, 3, 3)), np.zeros((1, 0, 3))) is None
    assert grid_nearest(np.array([[[np.nan, 0, 0]]]), np.zeros((1, 2, 3))) is None
    assert grid_nearest(np.array([[[1e12, 0, 0]]]), np.zeros((1, 2, 3))) is None
    # nearest_indices then answers with the k-d tree
    q = torch.tensor([[[1e12, 0.0, 0.0], [1.0, 0.0, 0.0]]], dtype=torch.float64)
    assert nearest_indices(q, torch.tensor([[[0.0, 0, 0], [2e12, 0, 0]]], dtype=torch.float64)).tolist() == [[0, 0]]


def test_six_dimensional_search_still_exact() -> None:
    q, r = torch.randn(2, 300, 6, dtype=torch.float64), torch.randn(2, 200, 6, dtype=torch.float64)
    assert torch.equal(nearest_indices(q, r), torch.cdist(q, r).argmin(-1))


def test_float32_inputs_and_gradients_through_nearest_distances(monkeypatch) -> None:
    gen = torch.Generator().manual_seed(3)
    q = torch.randn(2, 800, 3, generator=gen, requires_grad=True)
    r = torch.randn(2, 600, 3, generator=gen, requires_grad=True)
    d, idx = nearest_distances(q, r)
    dense = torch.cdist(q.double(), r.double()).min(-1)
    assert torch.equal(idx, dense.indices)
    torch.testing.assert_close(d.double(), dense.values)
    g = torch.autograd.grad(d.sum(), (q, r))
    monkeypatch.setattr(nn_search, "grid_nearest", lambda q, r: None)  # the former k-d tree path
    d_tree, _ = nearest_distances(q, r)
    assert torch.equal(d, d_tree)
    for a, b in zip(g, torch.autograd.grad(d_tree.sum(), (q, r))):
        assert torch.equal(a, b)


@pytest.mark.parametrize("template, match_normals", [("airplane", 0.0), ("car", 0.0), ("mug", 0.1)])
def test_training_loss_terms_identical_with_kdtree_matching(template: str, match_normals: float, monkeypatch) -> None:
    tpl = load_template(template)
    obj = Objective(tpl, n_points=1500, match_normals=match_normals)
    gen = torch.Generator().manual_seed(5)
    params = tpl.initial_params()[None].repeat(2, 1)
    params = params + 0.02 * torch.randn(params.shape, generator=gen)
    pts = torch.randn(2, 1500, 3, generator=gen)
    pts = 0.6 * pts / pts.norm(dim=-1, keepdim=True)
    names = [*obj.group_of_label, "body"]  # car: wheels in one group, the rest in the other
    batch = {
        "points": torch.cat([pts, pts / 0.6], -1),
        "meta": [{"point_part_names": names}] * 2,
        "point_parts": torch.randint(0, len(names), (2, 1500), generator=gen),
    }
    w = LossWeights(collision=0.0)
    st = obj.sample_st(gen)
    grid = obj.batch_terms(params, batch, st, w)
    monkeypatch.setattr(nn_search, "grid_nearest", lambda q, r: None)  # the former k-d tree path
    tree = obj.batch_terms(params, batch, st, w)
    for name in grid:
        assert torch.equal(grid[name], tree[name]), name


def test_far_candidate_does_not_overflow_the_box() -> None:
    # consecutive queries of one bucket far apart: the first answer is a useless start for the next
    r = np.array([[[0.0, 0, 0], [1e8, 1e8, 1e8], [1e8 + 1, 1e8, 1e8]]])
    q = np.array([[[1.0, 0, 0], [1e8 + 0.9, 1e8, 1e8], [2.0, 0, 0]]])
    np.testing.assert_array_equal(grid_nearest(q, r), [[0, 2, 0]])


@pytest.mark.parametrize("dim", [3, 6])
def test_the_fused_kernels_expression_finds_the_nearest_point(dim: int) -> None:
    q, r = RNG.normal(size=(2, 400, dim)), RNG.normal(size=(2, 300, dim))
    got = nn_search.squared_distance_argmin(torch.from_numpy(q), torch.from_numpy(r)).numpy()
    assert np.array_equal(got, kdtree(q, r))


def test_without_a_compiler_the_gpu_search_falls_back_to_cdist(monkeypatch) -> None:
    def broken(*args, **kwargs):
        raise RuntimeError("no backend")

    monkeypatch.setattr(nn_search, "COMPILED_SEARCH", nn_search.CompiledSearch(compile_fn=broken))
    q, r = torch.rand(2, 50, 3), torch.rand(2, 40, 3)
    with pytest.warns(UserWarning, match="fused nearest-neighbour kernel unavailable .*no backend.*using cdist"):
        first = nn_search.fused_nearest(q, r)
    assert torch.equal(first, nn_search.device_nearest(q, r))
    assert isinstance(nn_search.COMPILED_SEARCH.failure, RuntimeError)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # said once: later calls go straight to cdist
        assert torch.equal(nn_search.fused_nearest(q, r), first)


def test_a_forced_search_holds_inside_its_block_only(monkeypatch) -> None:
    taken = []
    monkeypatch.setattr(
        nn_search, "fused_nearest", lambda q, r: taken.append("fused") or nn_search.device_nearest(q, r)
    )
    monkeypatch.setattr(nn_search, "grid_nearest", lambda q, r: taken.append("grid") or kdtree(q, r))
    q, r = torch.rand(1, 30, 3), torch.rand(1, 20, 3)
    expected = torch.cdist(q, r).argmin(-1)
    with nn_search.forced_search("fused"):
        assert torch.equal(nn_search.nearest_indices(q, r), expected)
        with nn_search.forced_search("cdist"):
            assert torch.equal(nn_search.nearest_indices(q, r), expected)
        assert torch.equal(nn_search.nearest_indices(q, r), expected)
    assert torch.equal(nn_search.nearest_indices(q, r), expected)
    assert taken == ["fused", "fused", "grid"]
    with pytest.raises(ValueError, match="unknown nearest-point search 'kd'"):
        with nn_search.forced_search("kd"):
            pass


@pytest.mark.slow
@pytest.mark.skipif(
    not (shutil.which("g++") or shutil.which("c++")), reason="inductor's CPU backend needs a C++ compiler"
)
def test_the_compiled_kernel_equals_its_expression() -> None:
    """torch.compile's fused reduction (inductor's C++ backend here, Triton on a GPU)."""
    q, r = torch.rand(2, 700, 3), torch.rand(2, 900, 3)
    assert torch.equal(nn_search.fused_nearest(q, r), nn_search.squared_distance_argmin(q, r))
    assert nn_search.COMPILED_SEARCH.failure is None
