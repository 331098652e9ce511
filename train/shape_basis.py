"""A category's shape space, read from fits: the output basis of ``fit --shape-basis N``.

The template is fitted to the first N models of the training split (the fit stage's fit,
``train.template_fit.fit_batch``: Adam on the control points, no sketch, no network), and the
principal directions of those fits, each scaled by its standard deviation, become the directions
the network's output layer moves the template along (``train.model.BasisReadout``).

Why: with a plain output layer one output is one coordinate of one control point, each Adam step
moves every coordinate on its own, and the Chamfer loss reaches the encoder only through that
zero-initialised layer, so the encoder learns slowly (docs/experiments.md, "The head is not the
limit"). In the basis one output unit is one standard deviation of a shape change that the
category's models actually show (a wing's sweep, a body's length), moving every control point
it involves together.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import torch

from pipeline.core.fit_settings import PatchFitSettings
from train.data import DataSettings, make_loader
from train.errors import UsageError
from train.objective import Objective
from train.template_fit import fit_batch
from train.templates import Template

# Fits per optimisation batch: bounds memory (the objective's tensors grow with the batch).
CHUNK = 64


@dataclasses.dataclass(frozen=True)
class ShapeBasis:
    """``directions`` (K, D): the fits' principal directions, each times its standard deviation,
    largest first; ``explained``: the share of the fits' variance the K directions hold;
    ``shapes``: how many fits they come from; ``cpu_s``: what fitting cost."""

    directions: np.ndarray
    explained: float
    shapes: int
    cpu_s: float = 0.0


def principal_basis(params: np.ndarray, variance: float = 0.99, max_directions: int = 128) -> ShapeBasis:
    """The principal directions of the rows of ``params`` (N, D) that hold ``variance`` of their
    spread (at most ``max_directions``, at most N - 1), each scaled by its standard deviation."""
    params = np.asarray(params, dtype=np.float64)
    n = len(params)
    if params.ndim != 2 or n < 2:
        raise ValueError(f"a shape basis needs at least 2 fitted shapes (N, D), got shape {params.shape}")
    if not 0 < variance <= 1:
        raise ValueError(f"variance must be in (0, 1], got {variance!r}")
    mean = params.mean(axis=0)
    _, s, vt = np.linalg.svd(params - mean, full_matrices=False)
    var = s**2
    total = float(var.sum())
    if total <= 0:
        raise ValueError("the fitted shapes are all the same: no direction to read out")
    share = np.cumsum(var) / total
    k = int(min(np.searchsorted(share, variance - 1e-12) + 1, max_directions, n - 1))
    std = s[:k] / np.sqrt(n - 1)
    # a direction's sign is arbitrary in the SVD: fix it so the same fits give the same basis
    signs = np.where(vt[:k][np.arange(k), np.abs(vt[:k]).argmax(axis=1)] < 0, -1.0, 1.0)
    directions = (vt[:k] * (std * signs)[:, None]).astype(np.float32)
    return ShapeBasis(directions, float(share[k - 1]), n)


def fitted_shapes(
    dataset: str,
    category: str,
    template: Template,
    shapes: int,
    settings: PatchFitSettings = PatchFitSettings(),
    seed: int = 0,
) -> np.ndarray:
    """The template fitted to the first ``shapes`` models of ``category``'s training split, (N, D)."""
    objective = Objective(template, settings.points, match_normals=template.match_normals)
    data = DataSettings(eval_views=1, n_points=settings.points, image_size=32)
    loader = make_loader(dataset, category, "train", data, 0, min(CHUNK, shapes), train=False)
    out: list[torch.Tensor] = []
    count = 0
    for batch in loader:
        take = min(len(batch["key"]), shapes - count)
        if take < len(batch["key"]):
            batch = {k: v[:take] for k, v in batch.items() if k in ("points", "point_parts", "meta", "key")}
        out.append(fit_batch(objective, batch, settings, seed, category))
        count += take
        if count >= shapes:
            break
    if count < 2:
        raise UsageError(
            f"{dataset}: the {category} training split has {count} model(s); a shape basis needs 2 or more"
        )
    return torch.cat(out).numpy()


def shape_basis(
    dataset: str,
    category: str,
    template: Template,
    shapes: int,
    seed: int = 0,
    variance: float = 0.99,
    max_directions: int = 128,
) -> ShapeBasis:
    """Fit the template to ``shapes`` training models and take their principal directions."""
    t0 = time.process_time()
    fits = fitted_shapes(dataset, category, template, shapes, seed=seed)
    basis = principal_basis(fits, variance, max_directions)
    return dataclasses.replace(basis, cpu_s=round(time.process_time() - t0, 1))
