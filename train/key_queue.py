"""Momentum keys for the contrastive term: the second drawing of each model encoded by the
weight average, and a queue of earlier such keys as extra negatives (as MoCo keeps them).

Why: with batch 8 the term has 7 negatives and sits near chance (ln 8) for thousands of airplane
steps. A queue of the training encoder's own earlier codes did not help (docs/experiments.md):
codes from an encoder that has moved since are told apart by their age. Keys from the slowly
moving average (``--ema``) stay comparable for hundreds of steps, so they can be queued.

The queue is a fixed ring of unit vectors and the models they came from; entries of the anchor's
own model are masked out of its negatives. It lives on the run's device and is not kept in
checkpoints: a resumed run starts it empty and fills it within ``size / batch`` steps.
"""

from __future__ import annotations

import zlib

import torch
import torch.nn.functional as F
from torch import Tensor


def model_ids(keys: list[str], device: torch.device) -> Tensor:
    """A 64-bit id per sample key (the model it was drawn from), stable across processes."""
    return torch.tensor([zlib.crc32(k.encode()) for k in keys], dtype=torch.int64, device=device)


class KeyQueue:
    """The last ``size`` keys (unit rows) and their model ids; empty slots have id -1."""

    def __init__(self, size: int, dim: int, device: torch.device):
        if size < 1:
            raise ValueError(f"a key queue needs size >= 1, got {size}")
        self.keys = torch.zeros(size, dim, device=device)
        self.ids = torch.full((size,), -1, dtype=torch.int64, device=device)
        self._next = 0

    def negatives_mask(self, ids: Tensor) -> Tensor:
        """(B, size) True where queue entry j may serve as a negative for anchor i: filled, and
        drawn from another model."""
        return (self.ids[None, :] >= 0) & (self.ids[None, :] != ids[:, None])

    @torch.no_grad()
    def push(self, keys: Tensor, ids: Tensor) -> None:
        """Add a batch of keys (B, C), normalized here, overwriting the oldest entries."""
        n = len(keys)
        slots = (self._next + torch.arange(n, device=self.ids.device)) % len(self.ids)
        self.keys[slots] = F.normalize(keys.detach().float(), dim=1)
        self.ids[slots] = ids
        self._next = (self._next + n) % len(self.ids)


class MomentumKeys:
    """The key side of the contrastive term: ``encoder`` is the weight average's network and
    ``queue`` (optional) the earlier keys.

    Keys are computed with batch statistics, as the training encoder computes its queries, but
    without moving the average's running statistics (BatchNorm momentum 0 for the pass): keys from
    its running statistics (eval mode) made the training network's own eval-mode output drift
    away from its training-mode output (airplane validation L_Ch 0.095 at step 100, 0.38 at 500,
    the training network's 0.82), while batch-statistics keys kept level with the recipe."""

    def __init__(self, encoder: torch.nn.Module, queue: KeyQueue | None):
        self.encoder = encoder
        self.queue = queue
        self._norms = [m for m in encoder.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]

    @torch.no_grad()
    def keys(self, pair_images: Tensor) -> Tensor:
        """(B, C) codes of the second drawings."""
        saved = [(m.momentum, m.training) for m in self._norms]
        for m in self._norms:
            m.momentum, m.training = 0.0, True
        try:
            return self.encoder.encode(pair_images)
        finally:
            for m, (momentum, training) in zip(self._norms, saved):
                m.momentum, m.training = momentum, training
