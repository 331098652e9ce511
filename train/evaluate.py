"""Evaluation on a split: the paper's ablation-table metrics plus peers' Chamfer and F-score,
for the trained network and for the template alone (the baseline every model must beat).

Metrics (means over samples):
  chamfer          the paper's L_Ch: unsquared distances, Jacobian-weighted on the patch side
  normal, flat, template_normal   the paper's loss terms of the same names
  intersecting_pairs   Σ of the smooth collision indicator / 2 ≈ number of intersecting patch pairs
  chamfer_sq_x1000 peers' Chamfer (AtlasNet / Pixel2Mesh): mean squared distances both ways, ×1000
  fscore           F-score at distance tau (default 0.01 of the unit-sphere frame)
"""

from __future__ import annotations

from pathlib import Path

import torch

from pipeline.atomic import write_json
from train.data import DataSettings, make_loader
from train.fit import Objective, load_checkpoint, model_from_checkpoint
from train.geometry.coons import coons_points
from train.losses.collision import collision_loss
from train.losses.weights import LossWeights
from train.nn_search import gather_points, nearest_indices
from train.templates import load_template

METRICS = ("chamfer", "normal", "flat", "template_normal", "intersecting_pairs", "chamfer_sq_x1000", "fscore")


def peer_metrics(patch_points: torch.Tensor, target: torch.Tensor, tau: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Squared Chamfer ×1000 and F-score per item; ``patch_points (B, Q, 3)``, ``target (B, M, 3)``."""
    d_pt = ((patch_points - gather_points(target, nearest_indices(patch_points, target))) ** 2).sum(-1)
    d_tp = ((target - gather_points(patch_points, nearest_indices(target, patch_points))) ** 2).sum(-1)
    cd = 1000.0 * (d_pt.mean(-1) + d_tp.mean(-1))
    precision = (d_pt < tau * tau).float().mean(-1)
    recall = (d_tp < tau * tau).float().mean(-1)
    f = 2 * precision * recall / (precision + recall).clamp_min(1e-12)
    return cd, f


def batch_metrics(objective: Objective, params: torch.Tensor, batch: dict, tau: float) -> dict[str, torch.Tensor]:
    points = batch["points"].to(params.device)
    st = objective.sample_st(None)
    valid = objective.valid_mask(batch["meta"], params.device)
    terms = objective.terms(params, points, st, valid, LossWeights(collision=0.0, symmetry=0.0))
    patches = objective.template.patches_from_params(params)
    pp = coons_points(patches, st.to(params.device))
    if valid is not None:  # absent optional parts do not count in the peers' metrics either
        pp = torch.where(valid[..., None], pp, pp.new_full((), 1e6))
    cd, f = peer_metrics(pp.flatten(1, 2), points[..., :3], tau)
    out = {k: terms[k] for k in ("chamfer", "normal", "flat", "template_normal")}
    out["intersecting_pairs"] = collision_loss(patches, objective.pairs) / 2.0
    out["chamfer_sq_x1000"], out["fscore"] = cd, f
    return out


@torch.no_grad()
def evaluate(
    checkpoint: str | Path,
    dataset: str | Path,
    split: str = "test",
    category: str | None = None,
    views: int = 1,
    tau: float = 0.01,
    limit: int | None = None,
    out: str | Path | None = None,
    batch_size: int = 8,
) -> dict:
    """Mean metrics of the network and of the template baseline; saved as JSON when ``out``."""
    ckpt = load_checkpoint(checkpoint)
    s = ckpt["settings"]
    template = load_template(s["template"])
    model = model_from_checkpoint(ckpt, template)
    objective = Objective(template, s["n_points"])
    data = DataSettings(eval_views=views, n_points=s["n_points"], image_size=s["image_size"])
    loader = make_loader(dataset, category or s["category"], split, data, 0, batch_size, train=False)
    sums = {"model": {k: 0.0 for k in METRICS}, "template": {k: 0.0 for k in METRICS}}
    count = 0
    base = template.initial_params()[None]
    for batch in loader:
        params = model(batch["images"], batch["view_mask"])
        for name, p in (("model", params), ("template", base.expand_as(params))):
            for k, v in batch_metrics(objective, p, batch, tau).items():
                sums[name][k] += float(v.sum())
        count += len(batch["key"])
        if limit and count >= limit:
            break
    result = {
        "checkpoint": str(checkpoint),
        "step": int(ckpt["step"]),
        "split": split,
        "samples": count,
        "views": views,
        "fscore_tau": tau,
        "chamfer_note": "chamfer = paper's unsquared Jacobian-weighted L_Ch; chamfer_sq_x1000 = peers' squared x1000",
        **{name: {k: v / max(count, 1) for k, v in vals.items()} for name, vals in sums.items()},
    }
    if out:
        write_json(out, result)
    return result


def format_table(result: dict) -> str:
    lines = [f"{'metric':<20}{'model':>14}{'template':>14}"]
    for k in METRICS:
        lines.append(f"{k:<20}{result['model'][k]:>14.6g}{result['template'][k]:>14.6g}")
    return "\n".join(lines)


