"""Interpolation between two predictions, in patch-parameter space and in latent space (the
network's first hidden layer), writing one mesh per in-between step and ``strip.png``: every
frame drawn small with the CAD kernel's clean verdict under it.

The frames of one series share one mesh connectivity (``quad_mesh_sequence``: one set of
per-curve counts, one weld), so ``patch_XX.obj`` differ only in vertex positions and can be
played back or blended as a morph."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from pipeline.core.atomic import atomic_path, write_json
from pipeline.core.images import contact_sheet, save_png
from pipeline.core.settings_io import setting
from pipeline.core.thumbnails import render_mesh
from train.errors import UsageError
from train.export.bicubic import coons_to_bezier
from train.export.kernel_check import kernel_verdict
from train.export.obj import write_obj
from train.export.quadmesh import QuadMesh, quad_mesh_sequence
from train.export.units import CadUnits
from train.fit import load_run
from train.predict import load_sketches

STRIP_TILE = 128  # pixels per frame in strip.png: small enough for a row of ten on a screen


def lerp(a: torch.Tensor, b: torch.Tensor, steps: int) -> list[torch.Tensor]:
    """``steps`` ≥ 2 points from a to b inclusive; the ends are a and b exactly."""
    return [a if k == 0 else b if k == steps - 1 else a + (b - a) * (k / (steps - 1)) for k in range(steps)]


def frame_is_clean(patches: np.ndarray) -> bool:
    """``predict``'s verdict on one frame: the bicubic nets, in millimetres as the STEP file
    holds them, sew into a solid that the CAD kernel finds free of self-interference."""
    verdict = kernel_verdict(coons_to_bezier(patches) * CadUnits().mm)
    return verdict.solid and verdict.clean


def write_strip(path: Path, rows: dict[str, list[QuadMesh]], clean: dict[str, list[bool]]) -> np.ndarray:
    """One row per series, one ``STRIP_TILE`` picture per frame, its verdict written under it."""
    images, labels = [], []
    for name, meshes in rows.items():
        for k, mesh in enumerate(meshes):
            images.append(render_mesh(mesh.vertices, mesh.triangles(), size=STRIP_TILE))
            labels.append(f"{name} {k}: {'clean' if clean[name][k] else 'NOT clean'}")
    sheet = contact_sheet(images, labels, cols=max(len(m) for m in rows.values()))
    save_png(path, sheet)
    return sheet


@dataclasses.dataclass(frozen=True)
class InterpolateSettings:
    """``python -m train interpolate``: one flag per field."""

    checkpoint: str = setting(help="checkpoint.pt or best.pt of a run")
    sketch_a: tuple[str, ...] = setting(help="drawing(s) of the first object")
    sketch_b: tuple[str, ...] = setting(help="drawing(s) of the second object")
    out: str = setting(help="output folder")
    steps: int = setting(5, "frames, the two ends included")


@torch.no_grad()
def interpolate(
    checkpoint: str | Path,
    sketch_a: list[str],
    sketch_b: list[str],
    out: str | Path,
    steps: int = 5,
    alpha: float = 25.0,
) -> dict:
    """Writes ``patch_XX.obj`` and ``latent_XX.obj`` (XX = 0..steps-1), ``params.npz``,
    ``strip.png`` and ``interpolation.json`` (with each frame's clean verdict)."""
    if not (isinstance(steps, int) and steps >= 2):  # both ends are always written
        raise UsageError(f"steps must be an integer >= 2 (the two ends included), got {steps!r} (--steps)")
    if Path(out).exists() and not Path(out).is_dir():
        raise UsageError(f"{out}: not a folder (--out)")
    run = load_run(checkpoint)
    model, template, size = run.model, run.template, run.settings.image_size
    ia, ib = (load_sketches(s, size, run.framing).tensor for s in (sketch_a, sketch_b))
    za, zb = model.latent(ia), model.latent(ib)
    pa, pb = model.decode_latent(za), model.decode_latent(zb)
    series = {"patch": lerp(pa, pb, steps), "latent": [model.decode_latent(z) for z in lerp(za, zb, steps)]}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    keep = template.active_patches()  # every optional part present, closing patches left out
    meshes, clean = {}, {}
    for name, params in series.items():
        frames = [template.patches_from_params(p.double())[0].numpy()[keep] for p in params]
        meshes[name] = quad_mesh_sequence(frames, alpha=alpha)
        clean[name] = [frame_is_clean(f) for f in frames]
        for k, mesh in enumerate(meshes[name]):
            write_obj(out / f"{name}_{k:02d}.obj", mesh.vertices, mesh.triangles())
    write_strip(out / "strip.png", meshes, clean)
    arrays = {name: torch.cat(ps).numpy() for name, ps in series.items()}
    with atomic_path(out / "params.npz") as tmp:
        np.savez(tmp, **arrays)
    shape = {name: {"vertices": len(m[0].vertices), "quads": len(m[0].faces)} for name, m in meshes.items()}
    summary = {"steps": steps, "num_params": int(pa.shape[-1]), "mesh": shape, "clean": clean}
    write_json(out / "interpolation.json", summary)
    return {**summary, "params": arrays}
