"""What the CAD kernel says of the training loss's own optimum: fits, not network outputs.

Fits the category's template to the first N targets of a split with the training loss (collision
term on, ``bench_fit_ceiling.fit_to_targets``, the fit stage's fit) and checks each fit three ways: the CAD kernel
(``train.export.kernel_check``, the clean verdict ``predict`` prints), the crossing count
``evaluate`` reports (the loss's 8 x 8 truncated triangulation) and the conforming quad mesh at
40 segments per unit (``patch_intersections``). The kernel's faults are split into patch pairs
that share a boundary in the template and pairs that do not. A network trained with this loss
cannot be expected to be cleaner than the fits, so this tells whether an unclean prediction is
the network's or the loss's.

Usage: OMP_NUM_THREADS=1 .venv/bin/python bench/probe_fit_kernel.py --dataset DS --category CAT
       [--template CAT|PATH] [--shapes 16] [--steps 300] [--collision 1.0] [--collision-grid 8]
       [--collision-truncate 1] [--fold 0]
       [--out bench/results/fit_kernel_CAT.json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch
from bench_fit_ceiling import _batch, _plain_chamfer, fit_to_targets

from pipeline.core.atomic import dumps_json, write_bytes
from train.export.bicubic import coons_to_bezier
from train.export.kernel_check import kernel_verdict
from train.export.quadmesh import patch_intersections
from train.export.units import CadUnits
from train.geometry.intersections import count_intersecting_pairs
from train.objective import Objective
from train.templates import load_template


def kernel_of_fits(
    dataset: str,
    category: str,
    template_name: str,
    shapes: int = 16,
    steps: int = 300,
    collision: float = 1.0,
    collision_grid: int = 8,
    n_points: int = 4000,
    collision_truncate: int = 1,
    fold: float = 0.0,
) -> dict:
    template = load_template(template_name)
    objective = Objective(
        template,
        n_points,
        match_normals=template.match_normals,
        collision_grid=collision_grid,
        collision_truncate=collision_truncate,
    )
    counted = Objective(template, n_points)  # evaluate's crossing count: always the 8 x 8 grid
    batch = _batch(dataset, category, "test", n_points, shapes)
    t0 = time.process_time()
    params = fit_to_targets(objective, batch, steps, collision=collision, fold=fold)
    fit_s = time.process_time() - t0
    adjacent = set(template.adjacency())
    mask = objective.patch_mask(batch["meta"], torch.device("cpu"))
    patches = template.patches_from_params(params.double())
    rows = []
    for b, key in enumerate(batch["key"]):
        keep = np.arange(template.num_patches) if mask is None else mask[b].nonzero()[:, 0].numpy()
        present = patches[b][torch.as_tensor(keep)].numpy()
        verdict = kernel_verdict(coons_to_bezier(present) * CadUnits().mm)
        named = [(int(keep[i]), int(keep[j])) for i, j in verdict.patch_pairs]
        fine = patch_intersections(present, alpha=40.0)
        rows.append(
            {
                "key": key,
                "kernel_clean": verdict.clean,
                "kernel_faults": verdict.faulty,
                "kernel_pairs_adjacent": sum(p in adjacent for p in named),
                "kernel_pairs_apart": sum(p not in adjacent for p in named),
                "evaluate_pairs": count_intersecting_pairs(
                    patches[b].float(), counted.pairs, None if mask is None else mask[b]
                ),
                "quad_mesh_pairs": len(fine.patch_pairs),
                "quad_mesh_folded": len(fine.folded_patches),
            }
        )
    with torch.no_grad():
        chamfer = float(_plain_chamfer(counted, params, batch).mean())

    def mean(k: str) -> float:
        return float(np.mean([r[k] for r in rows]))

    return {
        "category": category,
        "template": template_name,
        "shapes": len(rows),
        "steps": steps,
        "collision": collision,
        "collision_grid": collision_grid,
        "collision_truncate": collision_truncate,
        "fold": fold,
        "fit_cpu_s": round(fit_s, 1),
        "fitted_chamfer": chamfer,
        "kernel_clean": sum(r["kernel_clean"] for r in rows),
        **{f"{k}_per_shape": mean(k) for k in rows[0] if k not in ("key", "kernel_clean")},
        "fits": rows,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dataset", required=True)
    p.add_argument("--category", required=True)
    p.add_argument("--template", default=None, help="a shipped name or a template file (default: the category's)")
    p.add_argument("--shapes", type=int, default=16)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--collision", type=float, default=1.0, help="the collision term's weight in the fit")
    p.add_argument("--collision-grid", type=int, default=8, help="the collision term's triangulation grid")
    p.add_argument("--collision-truncate", type=int, default=1, help="grid rows left out along shared seams (0: none)")
    p.add_argument("--fold", type=float, default=0.0, help="the fold term's weight in the fit (0: off)")
    p.add_argument("--out", default=None)
    a = p.parse_args()
    torch.set_num_threads(1)
    res = kernel_of_fits(
        a.dataset,
        a.category,
        a.template or a.category,
        a.shapes,
        a.steps,
        a.collision,
        a.collision_grid,
        collision_truncate=a.collision_truncate,
        fold=a.fold,
    )
    print(json.dumps({k: v for k, v in res.items() if k != "fits"}, indent=1))
    if a.out:
        write_bytes(a.out, dumps_json(res).encode())


if __name__ == "__main__":
    main()
