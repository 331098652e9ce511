"""Prediction from sketches and export of the result.

Writes to the output folder: ``patches.json`` (template format with the predicted geometry),
``patches.npy`` (P, 4, 4, 3), ``mesh.obj`` (welded watertight triangles), ``quads.obj`` (quad
mesh from the subdivision integer program), ``patches.igs`` (exact bicubic NURBS, IGES 5.3) and
``render.png``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import torch

from pipeline.atomic import write_npy
from pipeline.errors import ModelError
from pipeline.sheets import save_png
from pipeline.thumbnails import render_mesh
from train.data import read_png, to_network
from train.export.bicubic import coons_to_bezier
from train.export.iges import write_iges
from train.export.obj import edge_report, write_obj
from train.export.quadmesh import quad_mesh
from train.fit import load_checkpoint, model_from_checkpoint
from train.model import SketchToPatches
from train.templates import FreePoint, JunctionPoint, Template, load_template, save_template


def load_sketches(paths: list[str | Path], size: int) -> torch.Tensor:
    """PNG sketches (black on white) -> (1, V, 1, size, size) network input."""
    imgs = []
    for p in paths:
        data = Path(p).read_bytes() if Path(p).exists() else b""
        try:
            img = read_png(data, size)
        except (ValueError, cv2.error) as exc:
            raise ModelError(p, f"not a readable image: {exc}") from exc
        imgs.append(to_network(img))
    return torch.from_numpy(np.stack(imgs))[None]


def load_predictor(checkpoint: str | Path) -> tuple[SketchToPatches, Template, dict]:
    ckpt = load_checkpoint(checkpoint)
    template = load_template(ckpt["settings"]["template"])
    return model_from_checkpoint(ckpt, template), template, ckpt


def predicted_template(template: Template, params: torch.Tensor) -> Template:
    """The template with its points moved to the prediction (junction t from the logits)."""
    pos = template.points_from_params(params[None].double())[0].numpy()
    offsets = np.cumsum([0] + [3 if isinstance(p, FreePoint) else 1 for p in template.points])
    points = []
    for i, p in enumerate(template.points):
        if isinstance(p, FreePoint):
            points.append(FreePoint(tuple(float(x) for x in pos[i])))
        else:
            points.append(JunctionPoint(p.curve, float(torch.sigmoid(params[offsets[i]].double()))))
    return dataclasses.replace(template, points=points, name=f"{template.name}-prediction",
                               metadata={**template.metadata, "predicted": True})  # fmt: skip


def export_patches(patches: np.ndarray, out: str | Path, quad_alpha: float = 12.0, tri_alpha: float = 40.0) -> dict:
    """All file exports of one patch set; returns a summary (counts, watertightness)."""
    out = Path(out)
    write_npy(out / "patches.npy", patches.astype(np.float32))
    write_iges(out / "patches.igs", coons_to_bezier(patches))
    qm = quad_mesh(patches, alpha=quad_alpha)
    write_obj(out / "quads.obj", qm.vertices, qm.faces, qm.patch_of_face)
    fine = quad_mesh(patches, alpha=tri_alpha)
    tris = fine.triangles()
    write_obj(out / "mesh.obj", fine.vertices, tris)
    save_png(out / "render.png", render_mesh(fine.vertices, tris, size=384))
    return {
        "patches": int(len(patches)),
        "quads": int(len(qm.faces)),
        "triangles": int(len(tris)),
        "mesh": edge_report(tris),
        "curve_counts": qm.counts.tolist(),
    }


@torch.no_grad()
def predict(checkpoint: str | Path, sketches: list[str | Path], out: str | Path, parts: dict[str, bool] | None = None) -> dict:
    model, template, ckpt = load_predictor(checkpoint)
    images = load_sketches(sketches, ckpt["settings"]["image_size"])
    params = model(images)[0]
    out = Path(out)
    save_template(predicted_template(template, params), out / "patches.json")
    # a part switched off drops its patches and brings in its closing patches: still closed
    keep = template.active_patches(parts)
    patches = template.patches_from_params(params[None].double())[0].numpy()[keep]
    return export_patches(patches, out)
