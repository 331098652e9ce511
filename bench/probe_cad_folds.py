"""Where the CAD kernel finds a network's predictions unclean, and what the crossing count sees.

For the first ``--shapes`` test predictions: the kernel's interfering patch pairs (OpenCASCADE's
self-interference check of the sewn solid, as ``predict`` runs it), how many of those pairs share
a boundary curve or corner in the template, the patches it finds folded through themselves, and
the training metric's crossing count (``count_intersecting_pairs``: grids of the patches with the
rows at a shared boundary left out) on the grid training uses (8) and on finer ones. A pair the
kernel names that no grid sees crosses within one grid row of the seam it shares.

Usage: .venv/bin/python bench/probe_cad_folds.py --checkpoint RUN/best.pt --dataset DS [--split test]
       [--shapes 16] [--grids 8 16] [--out F.json]
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import numpy as np
import torch

from train.data import DataSettings, make_loader
from train.evaluate import cad_verdicts
from train.fit import load_run
from train.geometry.intersections import count_intersecting_pairs
from train.geometry.patch_pairs import collision_pairs
from train.objective import Objective


def _rows(run, objective: Objective, dataset: str, split: str, grids: tuple[int, ...]):
    """One row per test prediction, in shard order."""
    s, template = run.settings, run.template
    labels = template.patch_labels or ["?"] * template.num_patches
    touching = {tuple(p) for p in objective.pairs.pairs[objective.pairs.partial_pairs()].tolist()}
    counted = {g: collision_pairs(template, grid=g) for g in grids}
    data = DataSettings(eval_views=1, n_points=s.n_points, image_size=s.image_size)
    for batch in make_loader(dataset, s.category, split, data, 0, 8, train=False):
        params = run.model(batch["images"], batch["view_mask"])
        mask = objective.patch_mask(batch["meta"], params.device)
        patches = template.patches_from_params(params.double())
        for b, verdict in enumerate(cad_verdicts(objective, params, batch["meta"])):
            present = torch.ones(len(patches[b]), dtype=torch.bool) if mask is None else mask[b]
            ids = present.nonzero().squeeze(1).tolist()  # the verdict counts present patches only
            named = {tuple(sorted((ids[i], ids[j]))) for i, j in verdict.patch_pairs}
            yield {
                "key": batch["key"][b],
                "kernel_pairs": len(named),
                "sharing_a_boundary": len(named & touching),  # pairs that share a curve or a corner
                "folded_patches": len(verdict.folded_patches),
                "named_parts": sorted({"/".join(sorted((labels[i], labels[j]))) for i, j in named}),
                "crossing_count": {
                    str(g): count_intersecting_pairs(patches[b], pairs, present) for g, pairs in counted.items()
                },
            }


@torch.no_grad()
def cad_folds(checkpoint: str, dataset: str, split: str = "test", shapes: int = 16, grids=(8, 16)) -> dict:
    run = load_run(checkpoint)
    objective = Objective(run.template, run.settings.n_points)
    rows = list(itertools.islice(_rows(run, objective, dataset, split, tuple(grids)), shapes))
    parts = sorted({name for r in rows for name in r["named_parts"]})
    named = sum(r["kernel_pairs"] for r in rows)
    summary = {
        "share_of_pairs_sharing_a_boundary": sum(r["sharing_a_boundary"] for r in rows) / max(1, named),
        "predictions_naming_each_part_pair": {name: sum(name in r["named_parts"] for r in rows) for name in parts},
        "median_kernel_pairs": float(np.median([r["kernel_pairs"] for r in rows])),
        "median_folded_patches": float(np.median([r["folded_patches"] for r in rows])),
        "median_crossing_count": {str(g): float(np.median([r["crossing_count"][str(g)] for r in rows])) for g in grids},
    }
    return {
        "checkpoint": checkpoint,
        "dataset": dataset,
        "split": split,
        "shapes": len(rows),
        "summary": summary,
        "rows": rows,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--split", default="test")
    ap.add_argument("--shapes", type=int, default=16)
    ap.add_argument("--grids", type=int, nargs="+", default=[8, 16])
    ap.add_argument("--out", help="write the result as JSON here too")
    a = ap.parse_args()
    torch.set_num_threads(1)
    res = cad_folds(a.checkpoint, a.dataset, a.split, a.shapes, tuple(a.grids))
    text = json.dumps(res, indent=1)
    if a.out:
        Path(a.out).write_text(text + "\n")
    print(json.dumps(res["summary"], indent=1))


if __name__ == "__main__":
    main()
