"""Does the network respond to the sketch? Output distances between sketches of different models
against those between two pencil variants of one model's view (and two views of one model).

Distance = mean Euclidean distance between the predicted surfaces' control points (unit-sphere
frame). A network that reads the sketch gives different-model distances well above the
variant distances (ratio >> 1); a network that outputs its mean shape gives ratio ~1 and tiny
distances.

Usage: .venv/bin/python bench/probe_sketch_response.py --checkpoint RUN/best.pt --dataset DS [--split test]
"""

from __future__ import annotations

import argparse
import glob
import json
from pathlib import Path

import numpy as np
import torch
import webdataset as wds

from train.data import read_png, sketch_table, to_network
from train.fit import load_run


@torch.no_grad()
def response(checkpoint: str, dataset: str, split: str = "test", limit: int = 64) -> dict[str, float]:
    run = load_run(checkpoint)
    s, template, model = run.settings, run.template, run.model
    urls = sorted(glob.glob(str(Path(dataset) / s.category / f"{split}-*.tar")))
    images = {"v0a": [], "v0b": [], "v1a": []}  # view 0 variant 0 / view 0 variant 1 / view 1 variant 0
    for raw in wds.WebDataset(urls, shardshuffle=False):
        table = sketch_table(raw)
        views = list(table)
        if len(views) < 2 or len(table[views[0]]) < 2:
            continue
        for key, name in (("v0a", table[views[0]][0]), ("v0b", table[views[0]][1]), ("v1a", table[views[1]][0])):
            images[key].append(to_network(read_png(raw[name], s.image_size)))
        if len(images["v0a"]) >= limit:
            break
    pts = {}
    for key, imgs in images.items():
        x = torch.from_numpy(np.stack(imgs))[:, None]  # (N, 1 view, 1, H, W)
        pts[key] = template.points_from_params(model(x, torch.ones(len(imgs), 1, dtype=torch.bool)))

    def dist(a, b):
        return float((a - b).norm(dim=-1).mean())

    n = len(pts["v0a"])
    other = torch.roll(pts["v0a"], 1, dims=0)  # each sketch against the next model's same view
    out = {
        "models": n,
        "different_models": dist(pts["v0a"], other),
        "same_view_other_variant": dist(pts["v0a"], pts["v0b"]),
        "same_model_other_view": dist(pts["v0a"], pts["v1a"]),
        "spread_about_mean": dist(pts["v0a"], pts["v0a"].mean(0, keepdim=True)),
    }
    out["ratio_models_to_variants"] = out["different_models"] / max(out["same_view_other_variant"], 1e-12)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--split", default="test")
    a = ap.parse_args()
    torch.set_num_threads(1)
    print(json.dumps(response(a.checkpoint, a.dataset, a.split), indent=1))


if __name__ == "__main__":
    main()
