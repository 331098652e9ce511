"""Interpolation between two predictions, in patch-parameter space and in latent space (the
network's first hidden layer), writing one mesh per in-between step."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from pipeline.core.atomic import atomic_path, write_json
from train.errors import UsageError
from train.export.obj import write_obj
from train.export.quadmesh import quad_mesh
from train.fit import load_run
from train.predict import load_sketches


def lerp(a: torch.Tensor, b: torch.Tensor, steps: int) -> list[torch.Tensor]:
    """``steps`` ≥ 2 points from a to b inclusive; the ends are a and b exactly."""
    return [a if k == 0 else b if k == steps - 1 else a + (b - a) * (k / (steps - 1)) for k in range(steps)]


@torch.no_grad()
def interpolate(
    checkpoint: str | Path, sketch_a: list[str], sketch_b: list[str], out: str | Path, steps: int = 5, alpha: float = 25.0
) -> dict:
    """Writes ``patch_XX.obj`` and ``latent_XX.obj`` (XX = 0..steps-1) and ``params.npz``."""
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
    for name, params in series.items():
        for k, p in enumerate(params):
            patches = template.patches_from_params(p.double())[0].numpy()[keep]
            mesh = quad_mesh(patches, alpha=alpha)
            write_obj(out / f"{name}_{k:02d}.obj", mesh.vertices, mesh.triangles())
    arrays = {name: torch.cat(ps).numpy() for name, ps in series.items()}
    with atomic_path(out / "params.npz") as tmp:
        np.savez(tmp, **arrays)
    summary = {"steps": steps, "num_params": int(pa.shape[-1])}
    write_json(out / "interpolation.json", summary)
    return {**summary, "params": arrays}
