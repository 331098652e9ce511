"""Contrastive term on the encoder's codes: two drawings of one model should encode alike.

The network otherwise learns the category's mean shape and reacts to the pencil more than to
the shape (BENCHMARKS.md, "Why the sketch contributes so little"). Given the codes of one drawing
per model and of another drawing of the same model (another view or pencil variant), InfoNCE
makes each code pick its partner out of the batch: what stays in the code is what the drawings of
a model share — its shape — and not the viewpoint or the pencil.
"""

from __future__ import annotations

import zlib

import torch
import torch.nn.functional as F
from torch import Tensor


def info_nce(
    codes: Tensor,
    pair_codes: Tensor,
    temperature: float = 0.1,
    negatives: Tensor | None = None,
    blocked: Tensor | None = None,
) -> Tensor:
    """Symmetric InfoNCE per item ``(B,)`` of two ``(B, C)`` code batches whose rows pair up.

    Codes are compared by cosine similarity; item i's loss is the cross-entropy of finding row i
    of the other batch among all its rows (and the rows of ``negatives`` (Q, C), unit codes of
    other drawings, e.g. a :class:`CodeQueue`'s), averaged over both directions. ``blocked``
    (B, Q), True where a negative is a drawing of item i's own model: left out of its row. A
    batch of one without negatives gives 0.
    """
    if codes.shape != pair_codes.shape or codes.dim() != 2:
        raise ValueError(
            f"codes must be two (B, C) batches of one shape, got {tuple(codes.shape)} and {tuple(pair_codes.shape)}"
        )
    extra = 0 if negatives is None else negatives.shape[0]
    if codes.shape[0] < 2 and not extra:
        return codes.new_zeros(codes.shape[0])
    a, b = F.normalize(codes, dim=1), F.normalize(pair_codes, dim=1)
    target = torch.arange(len(a), device=a.device)
    rows = []
    for x, y in ((a, b), (b, a)):
        logits = x @ y.T
        if extra:
            queued = x @ negatives.T
            if blocked is not None:
                queued = queued.masked_fill(blocked, float("-inf"))
            logits = torch.cat([logits, queued], dim=1)
        rows.append(F.cross_entropy(logits / temperature, target, reduction="none"))
    return 0.5 * (rows[0] + rows[1])


def model_ids(keys: list[str]) -> Tensor:
    """(B,) integers naming each sample's model (its key's CRC-32): what ``CodeQueue`` compares."""
    return torch.tensor([zlib.crc32(k.encode()) for k in keys], dtype=torch.int64)


class CodeQueue:
    """The unit codes of the last ``size`` drawings the contrastive term saw, and their models.

    InfoNCE within a batch of 8 asks each drawing to pick its partner out of 8; the airplane's
    term stayed near that chance level (ln 8) for thousands of steps. Earlier steps' codes
    (detached, as in a memory bank) make the task 8 out of 8 + ``size`` for one encoder pass; a
    negative of the anchor's own model is masked (``blocked``). The queue is not checkpointed:
    a resumed run refills it within ``size`` / 2B steps."""

    def __init__(self, size: int):
        if size < 1:
            raise ValueError(f"a code queue holds at least 1 code, got {size}")
        self.size = size
        self.codes: Tensor | None = None  # (n, C), n <= size, newest last
        self.models: Tensor | None = None  # (n,) model ids as integers

    def negatives(self, models: Tensor) -> tuple[Tensor | None, Tensor | None]:
        """The queued codes and, for a batch of model ids (B,), the (B, n) mask of its own models."""
        if self.codes is None:
            return None, None
        return self.codes, models[:, None].to(self.models.device) == self.models[None, :]

    @torch.no_grad()
    def push(self, codes: Tensor, models: Tensor) -> None:
        """Queue (B, C) codes of drawings of models (B,), dropping the oldest beyond ``size``."""
        unit = F.normalize(codes.detach(), dim=1)
        models = models.to(unit.device)
        if self.codes is not None:
            unit, models = torch.cat([self.codes, unit]), torch.cat([self.models, models])
        self.codes, self.models = unit[-self.size :], models[-self.size :]
