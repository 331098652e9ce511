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

import copy
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


# The key encoder's own momentum, constant from the first step (MoCo's): the weight average's
# decay warms up (0.991 at step 1,000), so its codes of 128 steps ago were already far from
# today's and a queue of them could be told apart by age.
KEY_MOMENTUM = 0.999


class MomentumKeys:
    """The key side of the contrastive term: a copy of the training encoder that follows it with
    a constant momentum (``update`` after every optimizer step) and encodes the second drawings
    in eval mode (its running statistics follow the trained encoder's too), and the queue of
    earlier keys (optional). Keys never see the query batch's statistics, so the codes cannot
    tell this batch's keys from the queue's by what the batch shares."""

    def __init__(self, encoder: torch.nn.Module, queue: KeyQueue | None, momentum: float = KEY_MOMENTUM):
        self.encoder = copy.deepcopy(encoder).eval().requires_grad_(False)
        self.queue = queue
        self.momentum = momentum
        live = encoder.state_dict(keep_vars=True)
        pairs = [(k, live[name].detach()) for name, k in self.encoder.state_dict().items()]
        self._floats = [(a, b) for a, b in pairs if a.is_floating_point()]

    @torch.no_grad()
    def keys(self, pair_images: Tensor) -> Tensor:
        """(B, C) codes of the second drawings (B, 1, H, W)."""
        return self.encoder(pair_images)

    @torch.no_grad()
    def update(self) -> None:
        for key, live in self._floats:
            key.lerp_(live, 1.0 - self.momentum)
