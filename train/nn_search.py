"""Nearest neighbours without a dense N×M matrix on CPU, with differentiable distances.

The search runs on detached coordinates: on CPU, 3-D points go to the exact hashed-grid search
of ``train.grid_nn`` (1.5-2.6x cheaper than a k-d tree per batch item on training's point
clouds, BENCHMARKS.md), other dimensions (normal-aware matching searches in 6-D) to scipy's cKDTree per batch
item; on a GPU (any device but the CPU), one fused brute-force kernel on that device
(``fused_nearest``: torch.compile turns the squared distances and their argmin into one
reduction, so no query × reference matrix is written to memory), which reads nothing back to
the host. Distances are then recomputed in torch from the gathered neighbours so gradients flow
to both point sets. ``forced_search`` makes one search answer everywhere inside a block, for
benchmarks comparing them and tests that want the GPU's path on a CPU.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import warnings
from typing import Callable, Iterator

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from train.grid_nn import grid_nearest

SEARCHES = ("auto", "fused", "cdist")
_SEARCH = contextvars.ContextVar("nn_search", default="auto")


@contextlib.contextmanager
def forced_search(name: str) -> Iterator[None]:
    """Inside the block every search takes ``name`` on any device: ``"fused"`` (the compiled
    kernel), ``"cdist"`` (the chunked matrix before it) or ``"auto"`` (the grid or k-d tree on a
    CPU, the fused kernel elsewhere). For benchmarks that compare them and tests that want the
    GPU's path on a CPU; training never sets it."""
    if name not in SEARCHES:
        raise ValueError(f"unknown nearest-point search {name!r}; one of {', '.join(SEARCHES)}")
    token = _SEARCH.set(name)
    try:
        yield
    finally:
        _SEARCH.reset(token)


def nearest_indices(query: Tensor, reference: Tensor) -> Tensor:
    """Index of the nearest ``reference`` point for each ``query`` point.

    ``query (B, N, D)``, ``reference (B, M, D)`` → ``(B, N)`` int64 on the query's device. Ties
    (equal distances, e.g. coincident reference points) go to the lowest index on the 3-D CPU
    path; elsewhere to whichever the k-d tree or argmin picks.
    """
    q, r = query.detach(), reference.detach()
    search = _SEARCH.get()
    if search == "cdist":
        return device_nearest(q, r)
    if search == "fused" or q.device.type != "cpu":  # on the tensors' own device: no host round trip
        return fused_nearest(q, r)
    qn = q.double().numpy()
    rn = r.double().numpy()
    idx = grid_nearest(qn, rn) if qn.shape[-1] == 3 else None
    if idx is None:
        idx = kdtree_nearest(qn, rn)
    return torch.from_numpy(idx)


def device_nearest(query: Tensor, reference: Tensor, chunk: int = 4096) -> Tensor:
    """``nearest_indices`` in torch alone (chunked ``cdist`` + ``argmin``), on any device: the GPU
    path before ``fused_nearest`` and its fallback (queries per chunk, so the distance matrix stays
    ``chunk`` × M per item)."""
    out = [torch.cdist(query[:, s : s + chunk], reference).argmin(dim=-1) for s in range(0, query.shape[1], chunk)]
    return torch.cat(out, dim=1)


def squared_distance_argmin(query: Tensor, reference: Tensor) -> Tensor:
    """Index of the nearest reference point by Σ_d (q_d − r_d)², written as one pointwise
    expression per coordinate followed by an argmin, the form torch.compile fuses into a single
    reduction kernel. Eager, it builds the (B, N, M) matrix: the reference ``fused_nearest``
    compiles, and its test on CPU."""
    d = None
    for k in range(query.shape[-1]):
        diff = query[:, :, None, k] - reference[:, None, :, k]
        d = diff * diff if d is None else d + diff * diff
    return d.argmin(dim=-1)


class CompiledSearch:
    """``squared_distance_argmin`` through torch.compile, disabled for the rest of the process at
    its first failure (it then answers ``None``, once with a warning)."""

    def __init__(self, compile_fn: Callable[..., Callable] = torch.compile) -> None:
        self._compile = compile_fn
        self.failure: Exception | None = None

    @functools.cached_property
    def _kernel(self) -> Callable[[Tensor, Tensor], Tensor]:
        # shapes are fixed through a run (patch samples, target points): one compilation per shape
        return self._compile(squared_distance_argmin, dynamic=False, fullgraph=True)

    def __call__(self, query: Tensor, reference: Tensor) -> Tensor | None:
        if self.failure is not None:
            return None
        try:
            return self._kernel(query.contiguous(), reference.contiguous())
        except Exception as exc:  # noqa: BLE001 - any compiler failure: the plain path still answers
            self.failure = exc
            warnings.warn(f"fused nearest-neighbour kernel unavailable ({type(exc).__name__}: {exc}); using cdist")
            return None


COMPILED_SEARCH = CompiledSearch()


def fused_nearest(query: Tensor, reference: Tensor) -> Tensor:
    """``nearest_indices`` on a GPU: ``squared_distance_argmin`` compiled to one kernel (exact
    squared distances, unlike cdist's matrix-product form). Where it cannot compile, the chunked
    cdist of ``device_nearest`` answers."""
    idx = COMPILED_SEARCH(query, reference)
    return device_nearest(query, reference) if idx is None else idx


def kdtree_nearest(query: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """One scipy cKDTree build + query per batch item: any dimension (``(B, N, D)``, ``(B, M, D)``
    → ``(B, N)``); the CPU path for D ≠ 3 and the reference the grid is measured against."""
    idx = np.empty(query.shape[:2], dtype=np.int64)
    for b in range(query.shape[0]):
        idx[b] = cKDTree(reference[b]).query(query[b], k=1, workers=1)[1]
    return idx


def gather_points(points: Tensor, idx: Tensor) -> Tensor:
    """``points (B, M, C)`` at ``idx (B, N)`` → ``(B, N, C)``."""
    return torch.gather(points, 1, idx[..., None].expand(*idx.shape, points.shape[-1]))


def nearest_distances(query: Tensor, reference: Tensor, squared: bool = False) -> tuple[Tensor, Tensor]:
    """Distance from each query point to its nearest reference point, differentiable.

    Returns ``(dist (B, N), idx (B, N))``; ``squared`` gives squared Euclidean distances. The
    unsquared distance uses sqrt of a clamped square (gradient 0, not NaN, at coincident points).
    """
    idx = nearest_indices(query, reference)
    sq = ((query - gather_points(reference, idx)) ** 2).sum(-1)
    return (sq if squared else torch.sqrt(sq.clamp_min(1e-24))), idx
