"""Does the network respond to the sketch? Output distances between sketches of different models
against those between two pencil variants of one model's view (and two views of one model).

Distance = mean Euclidean distance between the predicted surfaces' control points (unit-sphere
frame). A network that reads the sketch gives different-model distances well above the
variant distances (ratio >> 1); a network that outputs its mean shape gives ratio ~1 and tiny
distances.

``--variant K`` reads pencil variant K (0: the dark line drawing, 1: the light, shaded one) for
the different-model and other-view distances; the variant distance is always K against the next
variant of the same view.

Usage: .venv/bin/python bench/probe_sketch_response.py --checkpoint RUN/best.pt --dataset DS [--split test]
       [--variant 0]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch
import webdataset as wds

from train.data import read_png, shard_urls, sketch_table, to_network, variant_member
from train.fit import load_run


@torch.no_grad()
def response(checkpoint: str, dataset: str, split: str = "test", limit: int = 64, variant: int = 0) -> dict[str, float]:
    run = load_run(checkpoint)
    s, template, model = run.settings, run.template, run.model
    urls = shard_urls(dataset, s.category, split)
    # view 0 in variant K / view 0 in the next variant / view 1 in variant K
    images = {"v0a": [], "v0b": [], "v1a": []}
    for raw in wds.WebDataset(urls, shardshuffle=False):
        table = sketch_table(raw)
        views = list(table)
        if len(views) < 2 or len(table[views[0]]) < 2:
            continue
        key = raw["__key__"]
        other = (variant + 1) % len(table[views[0]])
        chosen = (
            ("v0a", variant_member(table[views[0]], variant, key)),
            ("v0b", variant_member(table[views[0]], other, key)),
            ("v1a", variant_member(table[views[1]], variant, key)),
        )
        for key, name in chosen:
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
    ap.add_argument("--split", default="test", help="train, val, test, or all (every split the dataset has)")
    ap.add_argument("--variant", type=int, default=0, help="pencil variant read (0: dark lines, 1: light, shaded)")
    a = ap.parse_args()
    torch.set_num_threads(1)
    out = response(a.checkpoint, a.dataset, a.split, variant=a.variant)
    print(json.dumps({"variant": a.variant, **out}, indent=1))


if __name__ == "__main__":
    main()
