"""Training's point matching alone: per-item k-d trees (scipy cKDTree, the former CPU path) vs
the exact hashed grid (``train.grid_nn``), both directions as ``match_points`` runs them.

Inputs as in a training step: a real batch of target points (``--batch-size`` items from the
shards) and the template's patch samples (``Objective.sample_st``, one (s, t) set shared by the
patches) under output noise ``--noise``, with the patch mask of each item (masked samples moved
far away on the target → patch side, as ``match_points`` does). Checks both give equal
distances (indices too, bar exact ties), then prints median seconds per batch (both directions)
over ``--repeats``, alternating the two, and the grid's first-call (compile or cache load) time.
``--on-target`` replaces the patch samples by the target points moved by ``--noise`` (a model
that fits: the clouds lie on each other, as late in training).

    OMP_NUM_THREADS=1 taskset -c 1 .venv/bin/python bench/bench_matching.py --dataset DS
        [--category airplane] [--template airplane] [--batch-size 8] [--repeats 15] [--on-target]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

from train.data import DataSettings, make_loader
from train.geometry.coons import evaluate_patches
from train.losses.chamfer import matching_sets
from train.nn_search import kdtree_nearest
from train.objective import Objective
from train.templates import load_template


def matching_inputs(dataset: str, category: str, template: str, batch: int, noise: float, on_target: bool = False):
    """The two (query, reference) pairs of one step's ``match_points``, float64 numpy."""
    tpl = load_template(template)
    objective = Objective(tpl)
    b = next(iter(make_loader(dataset, category, "train", DataSettings(max_views=1), 0, batch, 0, True)))
    gen = torch.Generator().manual_seed(0)
    params = tpl.initial_params()[None].repeat(batch, 1)
    params = params + noise * torch.randn(params.shape, generator=gen)
    ev = evaluate_patches(tpl.patches_from_params(params), objective.sample_st(gen))
    mask = objective.patch_mask(b["meta"], torch.device("cpu"))
    pp = ev.points.reshape(batch, -1, 3).double()
    target = b["points"][..., :3].double()
    if on_target:
        pp, mask = target + noise * torch.randn(target.shape, generator=gen, dtype=target.dtype), None
    valid = None if mask is None else mask[:, :, None].expand(ev.points.shape[:3])
    pp, target, search = matching_sets(pp, target, valid)  # (B, N, 3) points flatten the same
    return [(pp.numpy(), target.numpy()), (target.numpy(), search.numpy())]  # match_points' two searches


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default="data/dataset", help="dataset folder (default: the one `make dataset` builds)")
    ap.add_argument("--category", default="airplane")
    ap.add_argument("--template", default="airplane")
    ap.add_argument("--batch-size", type=int, default=8)
    ap.add_argument("--noise", type=float, default=0.02)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--on-target", action="store_true", help="patch samples = target points + noise")
    a = ap.parse_args()
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    from train.grid_nn import grid_nearest

    grid_nearest(np.zeros((1, 1, 3)), np.zeros((1, 1, 3)))
    first = time.perf_counter() - t0
    pairs = matching_inputs(a.dataset, a.category, a.template, a.batch_size, a.noise, a.on_target)
    for q, r in pairs:
        gi, ki = grid_nearest(q, r), kdtree_nearest(q, r)
        dg = ((q - np.take_along_axis(r, gi[..., None], 1)) ** 2).sum(-1)
        dk = ((q - np.take_along_axis(r, ki[..., None], 1)) ** 2).sum(-1)
        assert np.array_equal(dg, dk), "grid and k-d tree distances differ"
        print(f"{q.shape[1]} -> {r.shape[1]} points: equal distances, indices equal for {np.mean(gi == ki):.6f}")
    times: dict[str, list[float]] = {"kdtree": [], "grid": []}
    for _ in range(a.repeats):
        for name, fn in (("kdtree", kdtree_nearest), ("grid", grid_nearest)):
            t = time.process_time()
            for q, r in pairs:
                fn(q, r)
            times[name].append(time.process_time() - t)
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"first grid call (compile or cache load, import included): {first:.2f} s")
    print(
        f"batch {a.batch_size}, both directions, median CPU s over {a.repeats}: "
        f"kdtree {med['kdtree']:.4f}  grid {med['grid']:.4f}  ratio {med['kdtree'] / med['grid']:.2f}x"
    )


if __name__ == "__main__":
    main()
