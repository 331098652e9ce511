"""Which of a shape's proportions does the network read from one drawing? Per test shape, the
target's extents along its own principal axes (longest, middle, thinnest) against the predicted
surface's and the blind mean's along the same axes.

For each axis: the targets' spread, the correlation of predicted with true extent, the slope of
that regression (1: read in full; 0: the same answer for every shape; between: the network
hedges toward its mean), the slope of truth on answer (~1: the answers are already the best
linear guess of the truth, so no rescaling of them helps) and the error of network and blind
mean. The same per view group: how squarely the drawn view (view 0, the one ``evaluate`` reads)
faces the thinnest axis, |cos| of the angle between the camera's line of sight and that axis
(near 1: a guitar drawn face-on, its depth unseen; near 0: drawn edge-on). Extents are
max - min of 4,000 samples of each surface.

``--fitted N`` answers the same for the template fitted directly to each of the split's first N
shapes (``bench/bench_fit_ceiling.py``'s fit, no sketch), with the mean of the fits as the blind
answer: what the template can express, the reference for the network's slopes.

Usage: .venv/bin/python bench/probe_extents.py --checkpoint RUN/best.pt --dataset DS [--split test]
       [--json OUT]
       .venv/bin/python bench/probe_extents.py --fitted 48 --category CAT --dataset DS [--steps 300]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch
import webdataset as wds

from pipeline.core.atomic import write_json
from train.data import DataSettings, shard_urls
from train.evaluate import blind_output, evaluation_batches
from train.fit import load_run
from train.geometry.sampling import sample_surface_uniform
from train.objective import Objective
from train.templates import load_template

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fit_ceiling import fit_to_targets  # noqa: E402  (a sibling bench script)

AXES = ("longest", "middle", "thinnest")
# view groups by |cos(line of sight, thinnest axis)|
VIEW_GROUPS = ((0.0, 0.5, "edge-on"), (0.5, 0.8, "oblique"), (0.8, 0.95, "nearly face-on"), (0.95, 1.01, "face-on"))


def principal_axes(points: np.ndarray) -> np.ndarray:
    """(3, 3): columns are the point set's principal directions, longest first."""
    centred = points - points.mean(0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return vt.T


def extents(points: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """(3,): max - min of the points projected on each column of ``axes``."""
    proj = points @ axes
    return proj.max(0) - proj.min(0)


def reading(true: np.ndarray, predicted: np.ndarray, blind: np.ndarray) -> dict[str, float]:
    """How well one extent is read over N shapes (1-D arrays of length N)."""
    spread = float(true.std())
    corr = float(np.corrcoef(true, predicted)[0, 1]) if spread > 0 and predicted.std() > 0 else 0.0
    slope = float(np.polyfit(true, predicted, 1)[0]) if spread > 0 else 0.0
    # ~1: the answers are already the best linear guess of the truth, so stretching them cannot help
    back = float(np.polyfit(predicted, true, 1)[0]) if predicted.std() > 0 else 0.0
    return {
        "shapes": len(true),
        "true_mean": float(true.mean()),
        "true_std": spread,
        "correlation": corr,
        "slope": slope,
        "slope_truth_on_answer": back,
        "rmse_network": float(np.sqrt(((predicted - true) ** 2).mean())),
        "rmse_blind": float(np.sqrt(((blind - true) ** 2).mean())),
    }


def first_view_directions(dataset: str, category: str, split: str) -> dict[str, np.ndarray]:
    """key -> view 0's line of sight (the camera's z axis in the model's frame)."""
    out = {}
    for raw in wds.WebDataset(shard_urls(dataset, category, split), shardshuffle=False):
        views = json.loads(raw["cameras.json"])["views"]
        out[raw["__key__"]] = np.asarray(views[0]["world_to_camera"], float)[2, :3]
    return out


def extent_rows(
    objective: Objective, answers: torch.Tensor, blind: torch.Tensor, batch: dict, generator: torch.Generator
) -> list[list[float]]:
    """Per batch item: the target's extents along its principal axes, then the answer's and the
    blind answer's along the same axes (9 values), and last the axes (3, 3) for the caller.
    Patches of optional parts the target lacks are left out, as ``evaluate`` does."""
    template = objective.template
    answered = template.patches_from_params(answers)
    mean = template.patches_from_params(blind.expand_as(answers))
    mask = objective.patch_mask(batch["meta"], answers.device)
    rows = []
    for b in range(len(answers)):
        target = batch["points"][b, :, :3].double().numpy()
        axes = principal_axes(target)
        found = []
        for patches in (answered[b], mean[b]):
            chosen = patches if mask is None else patches[mask[b]]
            samples = sample_surface_uniform(chosen, len(target), generator)[0].double().numpy()
            found.extend(extents(samples, axes))
        rows.append([*extents(target, axes), *found, axes])
    return rows


@torch.no_grad()
def probe(checkpoint: str, dataset: str, split: str = "test", n_points: int = 4000) -> dict:
    run = load_run(checkpoint)
    s, model = run.settings, run.model
    data = DataSettings(eval_views=1, eval_variant=0, n_points=n_points, image_size=s.image_size)
    blind = blind_output(model, dataset, s.category, data)[None]
    sight = first_view_directions(dataset, s.category, split)
    objective = Objective(run.template, n_points)
    generator = torch.Generator().manual_seed(0)
    rows = []  # |cos|, true (3), network (3), blind (3)
    for batch in evaluation_batches(dataset, s.category, split, data, 8):
        params = model(batch["images"], batch["view_mask"])
        for key, (*found, axes) in zip(batch["key"], extent_rows(objective, params, blind, batch, generator)):
            rows.append([abs(float(sight[key] @ axes[:, 2])), *found])
    r = np.asarray(rows)
    groups = {}
    for lo, hi, name in VIEW_GROUPS:
        mask = (r[:, 0] >= lo) & (r[:, 0] < hi)
        if mask.sum() >= 3:
            groups[f"{name} (|cos| {lo:g}-{min(hi, 1):g})"] = summarize(r[mask, 1:])
    return {
        "checkpoint": checkpoint,
        "category": s.category,
        "split": split,
        "all": summarize(r[:, 1:]),
        "by_view": groups,
    }


def summarize(r: np.ndarray) -> dict:
    """(N, 9) rows of true, answered and blind extents (3 each) -> a reading per axis."""
    return {name: reading(r[:, i], r[:, 3 + i], r[:, 6 + i]) for i, name in enumerate(AXES)}


@torch.no_grad()
def probe_fitted(dataset: str, category: str, split: str = "test", shapes: int = 48, steps: int = 300) -> dict:
    """The same reading for the template fitted to each of the first ``shapes`` targets."""
    n_points = 4000
    data = DataSettings(eval_views=1, n_points=n_points, image_size=64)
    batch = next(iter(evaluation_batches(dataset, category, split, data, shapes)))
    objective = Objective(load_template(category), n_points)
    with torch.enable_grad():
        params = fit_to_targets(objective, batch, steps)
    generator = torch.Generator().manual_seed(0)
    rows = [found for *found, _ in extent_rows(objective, params, params.mean(0, keepdim=True), batch, generator)]
    return {"fitted": category, "steps": steps, "split": split, "all": summarize(np.asarray(rows)), "by_view": {}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoint", help="the network to probe (or --fitted)")
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--fitted", type=int, default=0, help="instead: the template fitted to this many shapes")
    ap.add_argument("--category", help="with --fitted: the category (its template is fitted)")
    ap.add_argument("--steps", type=int, default=300, help="with --fitted: Adam steps of the fit")
    ap.add_argument("--split", default="test", help="train, val, test, or all (every split the dataset has)")
    ap.add_argument("--json", help="write the result here too")
    a = ap.parse_args()
    if bool(a.fitted) == bool(a.checkpoint) or (a.fitted and not a.category):
        ap.error("give --checkpoint, or --fitted N with --category")
    torch.set_num_threads(1)
    if a.fitted:
        out = probe_fitted(a.dataset, a.category, a.split, a.fitted, a.steps)
    else:
        out = probe(a.checkpoint, a.dataset, a.split)
    for group, axes in {"all": out["all"], **out["by_view"]}.items():
        print(group)
        for name, v in axes.items():
            print(
                f"  {name:<9} n {v['shapes']:>3}  true {v['true_mean']:.3f} ± {v['true_std']:.3f}  "
                f"corr {v['correlation']:.2f}  slope {v['slope']:.2f} (back {v['slope_truth_on_answer']:.2f})  "
                f"rmse network {v['rmse_network']:.4f} / blind {v['rmse_blind']:.4f}"
            )
    if a.json:
        write_json(a.json, out)


if __name__ == "__main__":
    main()
