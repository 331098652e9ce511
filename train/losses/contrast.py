"""Contrastive term on the encoder's codes: two drawings of one model should encode alike.

The network otherwise learns the category's mean shape and reacts to the pencil more than to
the shape (BENCHMARKS.md, "Why the sketch contributes so little"). Given the codes of one drawing
per model and of another drawing of the same model (another view or pencil variant), InfoNCE
makes each code pick its partner out of the batch: what stays in the code is what the drawings of
a model share — its shape — and not the viewpoint or the pencil.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor


def info_nce(codes: Tensor, pair_codes: Tensor, temperature: float = 0.1) -> Tensor:
    """Symmetric InfoNCE per item ``(B,)`` of two ``(B, C)`` code batches whose rows pair up.

    Codes are compared by cosine similarity; item i's loss is the cross-entropy of finding row i
    of the other batch among all its rows, averaged over both directions. A batch of one has no
    negatives and gives 0.
    """
    if codes.shape != pair_codes.shape or codes.dim() != 2:
        raise ValueError(
            f"codes must be two (B, C) batches of one shape, got {tuple(codes.shape)} and {tuple(pair_codes.shape)}"
        )
    if codes.shape[0] < 2:
        return codes.new_zeros(codes.shape[0])
    a, b = F.normalize(codes, dim=1), F.normalize(pair_codes, dim=1)
    logits = a @ b.T / temperature
    target = torch.arange(len(a), device=a.device)
    return 0.5 * (
        F.cross_entropy(logits, target, reduction="none") + F.cross_entropy(logits.T, target, reduction="none")
    )
