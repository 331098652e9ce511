"""Area-weighted Chamfer (L_Ch) forward + backward: k-d tree nearest neighbours vs dense torch.cdist.

Setting of the paper: batch 8, 7000 patch samples (sphere54 template, k² per patch) and 7000
target points per item, CPU, one thread. Prints both values (must agree) and median times.

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_chamfer.py [--repeats 5] [--template sphere54]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from train.geometry import evaluate_patches, sample_surface_uniform, samples_per_patch, uniform_params
from train.losses import chamfer_loss
from train.templates import load_template


def dense_chamfer(points: torch.Tensor, jac: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Same L_Ch with a dense (N×M) distance matrix per batch item."""
    pp = points.reshape(points.shape[0], -1, 3)
    w = jac.reshape(jac.shape[0], -1)
    out = []
    for b in range(pp.shape[0]):
        d = torch.cdist(pp[b], target[b])  # (N, M)
        out.append((d.min(1).values * w[b]).sum() / w[b].sum() + d.min(0).values.mean())
    return torch.stack(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--template", default="sphere54")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--points", type=int, default=7000)
    args = ap.parse_args()
    torch.set_num_threads(1)
    tpl = load_template(args.template)
    gen = torch.Generator().manual_seed(0)
    prm = tpl.initial_params()[None].repeat(args.batch, 1)
    prm = prm + 0.02 * torch.randn(prm.shape, generator=gen)
    k2 = samples_per_patch(args.points, tpl.num_patches)
    with torch.no_grad():
        target, _ = sample_surface_uniform(tpl.patches_from_params(prm) * 1.05, args.points, gen)
    st = uniform_params(tpl.num_patches, k2, gen)

    def run(fn):
        x = prm.clone().requires_grad_(True)
        t0 = time.perf_counter()
        ev = evaluate_patches(tpl.patches_from_params(x), st)
        value = fn(ev.points, ev.jacobian, target)
        value.sum().backward()
        return time.perf_counter() - t0, value.detach(), x.grad

    results = {}
    for name, fn in (("kdtree", chamfer_loss), ("dense_cdist", dense_chamfer)):
        times = []
        for _ in range(args.repeats):
            dt, value, grad = run(fn)
            times.append(dt)
        results[name] = (statistics.median(times), value, grad)
        print(
            f"{name:12s} median {statistics.median(times) * 1000:8.1f} ms  (batch {args.batch}, "
            f"{tpl.num_patches * k2} patch samples x {args.points} target points)"
        )
    (tk, vk, gk), (td, vd, gd) = results["kdtree"], results["dense_cdist"]
    print(f"max |value diff| {float((vk - vd).abs().max()):.2e}   max |grad diff| {float((gk - gd).abs().max()):.2e}")
    print(f"speed-up dense/kdtree: {td / tk:.2f}x")


if __name__ == "__main__":
    main()
