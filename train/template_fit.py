"""A template fitted to target shapes directly: Adam on its parameters, no sketch, no network.

Shared by the fit stage (``train.patch_fit``, which writes each model's fit into the dataset) and
the output basis of training (``train.shape_basis``, which fits a run's first training models).
"""

from __future__ import annotations

import torch

from pipeline.core.fit_settings import PatchFitSettings
from pipeline.core.seeding import derive_seed
from train.losses.total import weighted_sum
from train.losses.weights import template_weights
from train.objective import Objective


def fit_batch(
    objective: Objective,
    batch: dict,
    settings: PatchFitSettings,
    seed: int,
    category: str,
    weights: dict[str, float] | None = None,
) -> torch.Tensor:
    """The template's parameters (B, D) fitted to each target of ``batch`` (the loader's layout):
    Adam from the template, the training loss with the collision term at ``settings.collision``
    (``weights``: other loss weights on top, e.g. a probe's fold term)."""
    template = objective.template
    weights = template_weights(template.regularizers, {**(weights or {}), "collision": settings.collision})
    params = template.initial_params()[None].expand(len(batch["points"]), -1).clone().requires_grad_(True)
    opt = torch.optim.Adam([params], lr=settings.lr)
    gen = torch.Generator().manual_seed(derive_seed(seed, "fit", category) % 2**63)
    for _ in range(settings.steps):
        terms = objective.batch_terms(params, batch, objective.sample_st(gen), weights)
        loss = weighted_sum(terms, weights).sum()  # a sum: each model's gradient is its own
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    return params.detach()
