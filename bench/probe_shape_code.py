"""Does the encoder learn to read shape from drawings it has not seen?

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


def anchor_grid(grid: int = 8) -> torch.Tensor:
    """``(grid³, 3)`` cell centres over [-1, 1]³."""
    c = (torch.arange(grid, dtype=torch.float32) + 0.5) / grid * 2 - 1
    return torch.stack(torch.meshgrid(c, c, c, indexing="ij"), dim=-1).reshape(-1, 3)


def distance_codes(points: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
    """``(B, M)``: distance from each anchor to the nearest of each shape's points ``(B, N, 3+)``."""
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
    anchors = anchor_grid()
    d = torch.cat([distance_codes(b["points"], anchors) for b in train_once]).double()
    mean = d.mean(0)
    _, s, vh = torch.linalg.svd(d - mean, full_matrices=False)
    k = min(a.dims, len(d) - 1)
    comps, scale = vh[:k].float(), (s[:k] / (len(d) - 1) ** 0.5).float()

    def code(points: torch.Tensor) -> torch.Tensor:
        return (distance_codes(points, anchors) - mean.float()) @ comps.T / scale

    encoder = ResNet18(1, a.width)
    head = torch.nn.Linear(encoder.out_features, k)
    opt = torch.optim.Adam([*encoder.parameters(), *head.parameters()], lr=a.lr)

    def predict(batch: dict) -> torch.Tensor:
        return head(encoder(batch["images"][:, 0]))

    # the fixed splits' codes once (they are targets, not data that changes)
    fixed = {
        name: [(b["images"][:, 0], code(b["points"])) for b in batches]
        for name, batches in (("train", train_once), ("val", val))
    }

    @torch.no_grad()
    def error(name: str) -> float:
        encoder.eval()
        total = sum(float((head(encoder(im)) - c).pow(2).mean(1).sum()) for im, c in fixed[name])
        encoder.train()
        return total / sum(len(c) for _, c in fixed[name])

    def mean_error(name: str) -> float:  # predicting the mean code (0)
        return float(torch.cat([c for _, c in fixed[name]]).pow(2).mean())

    print(
        f"{a.category}: {len(d)} training shapes, {k} components; predicting the mean: "
        f"train {mean_error('train'):.3f}, val {mean_error('val'):.3f}",
        flush=True,
    )
    stream = iter(
        make_loader(a.dataset, a.category, "train", DataSettings(max_views=1, n_points=a.points), 0, 8, 1, True)
    )
    t0, recent = time.process_time(), []
    for step in range(1, a.steps + 1):
        batch = next(stream)
        loss = (predict(batch) - code(batch["points"])).pow(2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        recent.append(float(loss.detach()))
        if step % 200 == 0:
            print(
                f"step {step}: batches {sum(recent[-200:]) / 200:.3f}, train {error('train'):.3f}, "
                f"val {error('val'):.3f} ({time.process_time() - t0:.0f} CPU s)",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
