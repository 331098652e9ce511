"""How far can a template go on each test shape at all? The per-shape ceiling of the quality table.

Fits the template's parameters directly to each target (no sketch, no network): Adam on the
control points of every shape of a split at once (the fit stage's fit), with the training loss
minus the collision term (for speed; the ceiling is about L_Ch), then reports the plain L_Ch the quality table uses
(`train evaluate`: nearest points, midpoint grid, no part groups) for the template, the fitted
shapes, the mean of the other shapes' fits as one constant answer for each shape (leave one out:
what a network that learned only the set's common shape, and read nothing, would score), and —
from an `evaluate` JSON when given — the network and the sketch-blind baseline.
If the fitted L_Ch is not 25 % below blind, no network can meet the "−25 % vs blind" goal with
this template: the template, not the sketch reading, limits the category.

Usage: OMP_NUM_THREADS=1 .venv/bin/python bench/bench_fit_ceiling.py --dataset DS --category CAT
       [--template CAT] [--split test] [--shapes 16] [--steps 300] [--lr 0.01] [--points 4000]
       [--leave-out LABEL ...] [--eval bench/results/eval_CAT_cpu.json] [--out bench/results/ceiling_CAT.json]
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from pipeline.core.atomic import dumps_json, write_bytes
from pipeline.core.fit_settings import PatchFitSettings
from train.data import DataSettings, make_loader
from train.losses.weights import LossWeights
from train.objective import Objective
from train.template_fit import fit_batch
from train.templates import load_template


def _batch(dataset: str, category: str, split: str, n_points: int, shapes: int) -> dict:
    data = DataSettings(eval_views=1, n_points=n_points, image_size=64)
    loader = make_loader(dataset, category, split, data, 0, shapes, train=False)
    return next(iter(loader))


def _plain_chamfer(objective: Objective, params: torch.Tensor, batch: dict) -> torch.Tensor:
    w = LossWeights(normal=0.0, flat=0.0, collision=0.0, template_normal=0.0, symmetry=0.0)
    return objective.batch_terms(params, batch, objective.sample_st(None), w, training=False)["chamfer"]


def fit_to_targets(
    objective: Objective, batch: dict, steps: int, lr: float = 0.01, collision: float = 0.0, fold: float = 0.0
) -> torch.Tensor:
    """The template fitted to each target of ``batch`` (B, D): the fit stage's fit
    (``train.template_fit.fit_batch``), the collision term at weight ``collision`` (default off,
    for speed: the ceiling is about L_Ch) and the fold term at ``fold``."""
    settings = PatchFitSettings(steps=steps, lr=lr, collision=collision)
    return fit_batch(objective, batch, settings, seed=0, category=objective.template.name or "", weights={"fold": fold})


def fit_ceiling(
    dataset: str,
    category: str,
    template_name: str,
    split: str = "test",
    shapes: int = 16,
    steps: int = 300,
    lr: float = 0.01,
    n_points: int = 4000,
    leave_out: tuple[str, ...] = (),
) -> dict:
    template = load_template(template_name)
    objective = Objective(template, n_points, leave_out=leave_out)
    batch = _batch(dataset, category, split, n_points, shapes)
    b = len(batch["key"])
    start = template.initial_params()[None].expand(b, -1).clone()
    params = fit_to_targets(objective, batch, steps, lr)
    with torch.no_grad():
        tpl = _plain_chamfer(objective, start, batch)
        fitted = _plain_chamfer(objective, params, batch)
        # with one shape there are no others to average
        common = _plain_chamfer(objective, (params.sum(0, keepdim=True) - params) / (b - 1), batch) if b > 1 else None
    return {
        "category": category,
        "template": template_name,
        "patches": template.num_patches,
        "split": split,
        "shapes": b,
        "steps": steps,
        "lr": lr,
        "points": n_points,
        **({"left_out": sorted(leave_out)} if leave_out else {}),
        "template_chamfer": float(tpl.mean()),
        "fitted_chamfer": float(fitted.mean()),
        "others_mean_chamfer": None if common is None else float(common.mean()),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dataset", default="data/dataset", help="dataset folder (default: the one `make dataset` builds)")
    p.add_argument("--category", default="knife")
    p.add_argument("--template", default=None, help="default: the category's template")
    p.add_argument("--split", default="test")
    p.add_argument("--shapes", type=int, default=16)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--lr", type=float, default=0.01)
    p.add_argument("--points", type=int, default=4000)
    p.add_argument(
        "--leave-out", nargs="*", default=[], help="patch labels absent in every target (as `evaluate --leave-out`)"
    )
    p.add_argument("--eval", default=None, help="an evaluate JSON of the same split: adds network and blind")
    p.add_argument("--out", default=None)
    a = p.parse_args()
    torch.set_num_threads(1)
    t0 = time.process_time()
    res = fit_ceiling(
        a.dataset, a.category, a.template or a.category, a.split, a.shapes, a.steps, a.lr, a.points, tuple(a.leave_out)
    )
    res["cpu_s"] = round(time.process_time() - t0, 1)
    if a.eval:
        ev = json.load(open(a.eval))
        res["network_chamfer"], res["blind_chamfer"] = ev["model"]["chamfer"], ev["blind"]["chamfer"]
        res["fitted_vs_blind"] = res["fitted_chamfer"] / res["blind_chamfer"] - 1
        if res["others_mean_chamfer"] is not None:
            res["others_mean_vs_blind"] = res["others_mean_chamfer"] / res["blind_chamfer"] - 1
    print(json.dumps(res, indent=1))
    if a.out:
        write_bytes(a.out, dumps_json(res).encode())


if __name__ == "__main__":
    main()
