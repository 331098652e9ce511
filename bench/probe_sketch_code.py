"""Is the shape in the sketch features? A ridge-regression probe from the encoder's 512-d code of
one sketch view to simple shape descriptors of the target (extent along x, y, z of its surface points,
and whether each optional part is present), fitted on the train split, scored (R²) on another.

High R² with a network whose outputs barely move (probe_sketch_response.py) means the information
reaches the encoder and the head does not use it yet (optimisation); low R² means the drawings
or the encoder lose it.

Usage: .venv/bin/python bench/probe_sketch_code.py --checkpoint RUN/best.pt --dataset DS [--eval-split val]
       (--init: the same architecture at its seeded initialisation instead of the checkpoint's weights;
        --pixels: the 16×16-pooled drawing itself, a reference for what a linear probe can get)
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from pipeline.core.schema import PRESENT_PARTS
from train.data import DataSettings, make_loader
from train.fit import build_network, load_run


@torch.no_grad()
def codes(model, dataset, category, split, parts, image_size):
    data = DataSettings(eval_views=4, n_points=2000, image_size=image_size)
    feats, desc, view = [], [], []
    for b in make_loader(dataset, category, split, data, 0, 8, train=False):
        pts = b["points"][..., :3].numpy()
        ext = pts.max(1) - pts.min(1)
        has = np.array([[float(p in (m.get(PRESENT_PARTS) or [])) for p in parts] for m in b["meta"]]).reshape(
            len(ext), -1
        )
        for v in range(b["images"].shape[1]):  # every view on its own: up to 4 samples per model
            on = b["view_mask"][:, v].numpy()
            if not on.any():
                continue
            img = b["images"][on, v : v + 1]
            if model is None:  # the drawing itself, 16×16 average-pooled ink
                feats.append(torch.nn.functional.adaptive_avg_pool2d(img[:, 0], 16).flatten(1).numpy())
            else:
                feats.append(model.encode(img).numpy())
            desc.append(np.concatenate([ext, has], 1)[on])
            view.append(np.full(int(on.sum()), v))
    return np.concatenate(feats), np.concatenate(desc), np.concatenate(view)


def r2_probe(xtr, ytr, xte, yte, alpha=10.0):
    mu, sd = xtr.mean(0), xtr.std(0) + 1e-6
    a, b = (xtr - mu) / sd, (xte - mu) / sd
    ym = ytr.mean(0)
    w = np.linalg.solve(a.T @ a + alpha * np.eye(a.shape[1]), a.T @ (ytr - ym))
    pred = b @ w + ym
    ss = ((yte - yte.mean(0)) ** 2).sum(0)
    return 1 - ((yte - pred) ** 2).sum(0) / np.maximum(ss, 1e-12)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--eval-split", default="val")
    ap.add_argument("--init", action="store_true")
    ap.add_argument("--pixels", action="store_true", help="probe the 16×16-pooled drawing instead of the encoder")
    a = ap.parse_args()
    torch.set_num_threads(1)
    run = load_run(a.checkpoint)
    s, tpl = run.settings, run.template
    if a.pixels:
        model = None
    elif a.init:
        torch.manual_seed(s.seed)
        model = build_network(s, tpl).eval()
    else:
        model = run.model
    parts = sorted(tpl.optional_parts)
    xtr, ytr, vtr = codes(model, a.dataset, s.category, "train", parts, s.image_size)
    xte, yte, vte = codes(model, a.dataset, s.category, a.eval_split, parts, s.image_size)
    names = ["extent_x", "extent_y", "extent_z"] + [f"has_{p}" for p in parts]
    out = {
        "weights": "pixels" if a.pixels else "init" if a.init else f"step {run.step}",
        "train views": len(xtr),
        f"{a.eval_split} views": len(xte),
    }
    for alpha in (1e2, 1e3, 1e4):
        r2 = r2_probe(xtr, ytr, xte, yte, alpha)
        out[f"r2 (ridge {alpha:g})"] = {n: round(float(v), 3) for n, v in zip(names, r2)}
        # one probe per view index (a fixed camera rig gives each index one viewpoint), R² averaged
        per = np.mean(
            [r2_probe(xtr[vtr == v], ytr[vtr == v], xte[vte == v], yte[vte == v], alpha) for v in np.unique(vte)], 0
        )
        out[f"r2 per view index (ridge {alpha:g})"] = {n: round(float(v), 3) for n, v in zip(names, per)}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
