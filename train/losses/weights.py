"""Loss weights, one field per entry of the term table (``train.losses.terms``), in its order;
a weight of 0 switches a term off. Also the trainer's weight and ablation flags, from the table."""

from __future__ import annotations

import argparse
from dataclasses import dataclass, fields, replace

from train.losses.terms import LOSS_TERMS as _TABLE


@dataclass(frozen=True)
class LossWeights:
    """Weight of each loss term (defaults: the paper's values for unit-sphere models)."""

    chamfer: float = 1.0
    normal: float = 0.008
    flat: float = 2.0
    collision: float = 1.0  # our L_coll is a penetration depth (docs/geometry.md), not the paper's indicator (1e-5)
    template_normal: float = 1e-4
    symmetry: float = 1.0
    fit: float = 0.0  # not in the paper: pulls the control points to the fit stage's (--fit-patches)
    fold: float = 0.0  # not in the paper: patches folded back over themselves (the CAD kernel's faults)


def only_term(name: str, weights: LossWeights | None = None) -> LossWeights:
    """Every weight 0 except ``name``'s (its value in ``weights``, default: the table's)."""
    weights = weights or LossWeights()
    return LossWeights(**{t.name: getattr(weights, t.name) if t.name == name else 0.0 for t in _TABLE})


def template_weights(regularizers: dict[str, float], overrides: dict[str, float] | None = None) -> LossWeights:
    """The paper's weights with the regularizers a template file names (``Template.regularizers``;
    regularizer terms are off unless named), then ``overrides`` (command line)."""
    off = {t.name: 0.0 for t in _TABLE if t.regularizer}
    bad = sorted(set(regularizers) - set(off))
    if bad:
        raise ValueError(f"template regularizers {bad}: expected some of {sorted(off)}")
    base = replace(LossWeights(), **{**off, **regularizers})
    names = {f.name for f in fields(LossWeights)}
    unknown = set(overrides or {}) - names
    if unknown:
        raise ValueError(f"unknown loss weights {sorted(unknown)}")
    return replace(base, **(overrides or {}))


def add_weight_flags(p: argparse.ArgumentParser) -> None:
    """``--w-<term>`` (a weight) for every term and ``--no-<term>`` (weight 0) for each ablatable one."""
    regs = " and ".join(t.name for t in _TABLE if t.regularizer)
    for t in _TABLE:
        p.add_argument(
            f"--w-{t.name.replace('_', '-')}",
            type=float,
            default=None,
            help=f"loss weight (paper: {getattr(LossWeights(), t.name)}; {regs} default to the template file's)",
        )
    for t in _TABLE:
        if t.ablation:
            p.add_argument(
                f"--no-{t.name.replace('_', '-')}", action="store_true", help=f"ablation: weight of {t.name} = 0"
            )


def weight_overrides(a: argparse.Namespace) -> dict[str, float]:
    """The weights the ``--w-<term>`` / ``--no-<term>`` flags set (only those given)."""
    vals = {t.name: getattr(a, f"w_{t.name}") for t in _TABLE}
    vals = {k: v for k, v in vals.items() if v is not None}
    for t in _TABLE:
        if t.ablation and getattr(a, f"no_{t.name}"):
            vals[t.name] = 0.0
    return vals


def weights_from_flags(a: argparse.Namespace, regularizers: dict[str, float]) -> LossWeights:
    """The table's weights, then the template file's ``regularizers``, then what the flags set."""
    return template_weights(regularizers, weight_overrides(a))
