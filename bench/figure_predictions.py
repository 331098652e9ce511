"""Figure: test sketch | prediction | ground truth, one row per test model.

Usage: .venv/bin/python bench/figure_predictions.py --checkpoint RUN/best.pt --dataset DS --work-dir WORK
       --out docs/images/quality_<category>.png [--rows 4] [--blind] [--variant 0]
       [--split all --blind-from TRAINING_DS --leave-out LABEL ...]   (meshes the network never saw)
       [--views 4]   (the network reads each model's first 4 drawings; the sketch column tiles them)
``--variant K`` draws each row's sketch in pencil variant K (0: the dark line drawing, 1: the
light, shaded one), and takes the blind mean over the same variant, as ``evaluate --variant`` does.
Ground truth is the prepared mesh (``WORK/prepare-*/<category>/<model_id>/mesh.ply``). ``--blind`` adds
the sketch-blind baseline of ``train evaluate`` (the mean network output over the train split) as a
last column, so a reader sees what the drawing changed in each prediction. For a folder of real
meshes, as ``train evaluate`` measures them: ``--split all``, the blind mean from the run's own
training data (``--blind-from``), and ``--leave-out`` the parts the targets lack (drawn as a model
without them: the part's patches off, its closing patches on).
"""

from __future__ import annotations

import argparse
import glob
import json
from pathlib import Path

import cv2
import numpy as np
import torch
import webdataset as wds

from pipeline.core.images import contact_sheet, save_png
from pipeline.core.schema import MESH_FILE, META_MEMBER, PRESENT_PARTS
from pipeline.core.thumbnails import render_mesh
from pipeline.sources.mesh_io import read_ply
from train.data import DataSettings, eval_members, read_png, shard_urls, sketch_table, to_network
from train.evaluate import blind_output
from train.fit import load_run
from train.geometry.triangulate import welded_mesh
from train.objective import Objective
from workflows.listing import work_id


@torch.no_grad()
def figure(
    checkpoint: str,
    dataset: str,
    work_dir: str,
    rows: int,
    size: int = 256,
    blind: bool = False,
    variant: int = 0,
    split: str = "test",
    blind_from: str | None = None,
    leave_out: tuple[str, ...] = (),
    views: int = 1,
) -> np.ndarray:
    run = load_run(checkpoint)
    s, template, model = run.settings, run.template, run.model
    objective = Objective(template, 500, leave_out=leave_out)
    cols = 4 if blind else 3
    mean_patches = None
    if blind:
        mean = blind_output(
            model,
            blind_from or dataset,
            s.category,
            DataSettings(eval_views=1, eval_variant=variant, image_size=s.image_size),
        )
        mean_patches = template.patches_from_params(mean[None])[0]
    urls = shard_urls(dataset, s.category, split)  # the shards evaluate reads ("all": every split's)
    images, labels = [], []
    for raw in wds.WebDataset(urls, shardshuffle=False):
        meta = json.loads(raw[META_MEMBER])
        names = eval_members(sketch_table(raw), views, variant, meta["model_id"])
        sketches = [read_png(raw[name], s.image_size) for name in names]
        x = torch.from_numpy(np.stack([to_network(k) for k in sketches]))[None]
        patches = template.patches_from_params(model(x, torch.ones(1, len(sketches), dtype=torch.bool)))[0]
        keep = objective.mask_for(meta.get(PRESENT_PARTS))
        v, f = welded_mesh(patches[keep].double(), 12)
        # a procedural model's work folder is its id, a folder source's its work id
        ids = [meta["model_id"]] + (
            [work_id(meta["model_id"], meta["source_sha256"])] if meta.get("source_sha256") else []
        )
        where = [Path(work_dir) / "prepare-*" / s.category / i / MESH_FILE for i in ids]
        gt = sorted(p for w in where for p in glob.glob(str(w)))
        if not gt:
            raise SystemExit(f"{meta['key']}: no prepared mesh at {' or '.join(map(str, where))} (--work-dir)")
        gv, gf = read_ply(gt[0])
        images += [tile(sketches, size), render_mesh(v, f, size), render_mesh(gv, gf, size)]
        labels += [f"{meta['model_id']} sketch" + ("es" if len(sketches) > 1 else ""), "prediction", "ground truth"]
        if mean_patches is not None:  # the same parts kept as for the prediction
            images.append(render_mesh(*welded_mesh(mean_patches[keep].double(), 12), size))
            labels.append("sketch-blind mean")
        if len(labels) >= cols * rows:
            break
    return contact_sheet(images, labels, cols=cols)


def tile(sketches: list[np.ndarray], size: int) -> np.ndarray:
    """The drawings a prediction read, in a square grid filling one ``size`` cell (white where
    the grid has no drawing)."""
    k = int(np.ceil(np.sqrt(len(sketches))))
    cell = size // k
    out = np.full((size, size), 255, np.uint8)
    for i, sk in enumerate(sketches):
        r, c = divmod(i, k)
        out[r * cell : (r + 1) * cell, c * cell : (c + 1) * cell] = cv2.resize(
            sk, (cell, cell), interpolation=cv2.INTER_NEAREST if cell >= sk.shape[0] else cv2.INTER_AREA
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--work-dir", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--rows", type=int, default=4)
    ap.add_argument("--blind", action="store_true", help="add the sketch-blind mean shape as a last column")
    ap.add_argument("--variant", type=int, default=0, help="pencil variant drawn (0: dark lines, 1: light, shaded)")
    ap.add_argument("--split", default="test", help="test, val, train, or all (every split: a folder of real meshes)")
    ap.add_argument("--blind-from", default=None, help="dataset whose train split gives the blind mean (real meshes)")
    ap.add_argument("--leave-out", nargs="*", default=(), help="parts the targets lack, drawn absent (TORCS: wheels)")
    ap.add_argument("--views", type=int, default=1, help="drawings of each model the network reads (evaluate --views)")
    a = ap.parse_args()
    if a.views < 1:
        ap.error(f"--views must be 1 or more, got {a.views}")
    fig = figure(
        a.checkpoint,
        a.dataset,
        a.work_dir,
        a.rows,
        blind=a.blind,
        variant=a.variant,
        split=a.split,
        blind_from=a.blind_from,
        leave_out=tuple(a.leave_out),
        views=a.views,
    )
    save_png(a.out, fig)
    print(a.out)


if __name__ == "__main__":
    main()
