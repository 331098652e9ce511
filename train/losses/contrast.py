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


def info_nce_keys(
    codes: Tensor,
    keys: Tensor,
    ids: Tensor,
    queue_keys: Tensor | None = None,
    queue_mask: Tensor | None = None,
    temperature: float = 0.1,
) -> Tensor:
    """InfoNCE per item ``(B,)`` of query codes ``(B, C)`` against fixed keys ``(B, C)`` of the same
    models (no gradient flows into the keys), with the batch's other models' keys and, if given,
    the unit ``queue_keys`` ``(K, C)`` where ``queue_mask`` ``(B, K)`` allows them as negatives.
    Keys of the anchor's own model (``ids`` equal, a model drawn twice in a batch) are masked."""
    if codes.shape != keys.shape or codes.dim() != 2 or ids.shape != codes.shape[:1]:
        raise ValueError(
            f"codes and keys must be two (B, C) batches of one shape with (B,) ids, got "
            f"{tuple(codes.shape)}, {tuple(keys.shape)} and {tuple(ids.shape)}"
        )
    q = F.normalize(codes, dim=1)
    k = F.normalize(keys.detach(), dim=1)
    batch = q @ k.T / temperature
    same = ids[:, None] == ids[None, :]
    batch = batch.masked_fill(same & ~torch.eye(len(q), dtype=torch.bool, device=q.device), float("-inf"))
    logits = batch
    if queue_keys is not None:
        if queue_mask is None or queue_mask.shape != (len(q), len(queue_keys)):
            raise ValueError("queue_keys need a (B, K) queue_mask")
        queued = (q @ queue_keys.detach().T / temperature).masked_fill(~queue_mask, float("-inf"))
        logits = torch.cat([batch, queued], dim=1)
    target = torch.arange(len(q), device=q.device)
    return F.cross_entropy(logits, target, reduction="none")
