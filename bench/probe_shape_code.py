"""Does the encoder learn to read shape from drawings it has not seen? (BENCHMARKS.md, stop 18)

Trains the network's encoder (ResNet-18 at ``--width``) and a linear head, nothing else, to predict
a shape code from one drawing: the ``--dims`` leading principal components, whitened over the
training split, of each target's distance field sampled at 8 × 8 × 8 anchors in the unit ball the
models are normalized to. Every 200 steps it prints the mean squared error of the code on the
training drawings (no jitter) and on the validation split; predicting the mean code scores about
1 on the training split (its "mean" figure is printed for both splits). A falling training error
with a flat validation error means the encoder tells the training models apart without learning
to read shape.

    OMP_NUM_THREADS=1 python bench/probe_shape_code.py --dataset data/q13 --category knife --lr 1e-3 --steps 1600
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from train.data import DataSettings, make_loader  # noqa: E402
from train.resnet import ResNet18  # noqa: E402


def distance_codes(points: torch.Tensor, grid: int = 8) -> torch.Tensor:
    """``(B, grid³)``: distance from each anchor (cell centres over [-1, 1]³) to the nearest point."""
    c = (torch.arange(grid, dtype=torch.float32) + 0.5) / grid * 2 - 1
    anchors = torch.stack(torch.meshgrid(c, c, c, indexing="ij"), dim=-1).reshape(-1, 3)
    xyz = points[..., :3]
    return torch.cdist(anchors.expand(len(xyz), -1, -1), xyz).amin(dim=2)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--category", required=True)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--steps", type=int, default=1600)
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--dims", type=int, default=16)
    ap.add_argument("--points", type=int, default=2000)
    a = ap.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    torch.manual_seed(0)
    once = DataSettings(eval_views=1, n_points=a.points)
    train_once = list(make_loader(a.dataset, a.category, "train", once, 0, 16, train=False))
    val = list(make_loader(a.dataset, a.category, "val", once, 0, 16, train=False))
    d = torch.cat([distance_codes(b["points"]) for b in train_once]).double()
    mean = d.mean(0)
    _, s, vh = torch.linalg.svd(d - mean, full_matrices=False)
    k = min(a.dims, len(d) - 1)
    comps, scale = vh[:k].float(), (s[:k] / (len(d) - 1) ** 0.5).float()

    def code(points: torch.Tensor) -> torch.Tensor:
        return (distance_codes(points) - mean.float()) @ comps.T / scale

    encoder = ResNet18(1, a.width)
    head = torch.nn.Linear(encoder.out_features, k)
    opt = torch.optim.Adam([*encoder.parameters(), *head.parameters()], lr=a.lr)

    def predict(batch: dict) -> torch.Tensor:
        return head(encoder(batch["images"][:, 0]))

    @torch.no_grad()
    def error(batches: list[dict], zero: bool = False) -> float:
        encoder.eval()
        total = sum(float(((0 if zero else predict(b)) - code(b["points"])).pow(2).mean(1).sum()) for b in batches)
        encoder.train()
        return total / sum(len(b["points"]) for b in batches)

    print(f"{a.category}: {len(d)} training shapes, {k} components; predicting the mean: "
          f"train {error(train_once, True):.3f}, val {error(val, True):.3f}", flush=True)
    stream = iter(make_loader(a.dataset, a.category, "train", DataSettings(max_views=1, n_points=a.points), 0, 8, 1, True))
    t0, recent = time.process_time(), []
    for step in range(1, a.steps + 1):
        batch = next(stream)
        loss = (predict(batch) - code(batch["points"])).pow(2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        recent.append(float(loss.detach()))
        if step % 200 == 0:
            print(f"step {step}: batches {sum(recent[-200:]) / 200:.3f}, train {error(train_once):.3f}, "
                  f"val {error(val):.3f} ({time.process_time() - t0:.0f} CPU s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
