"""Train/val/test assignment from a hash of the model id.

The split of a model depends only on its own id (and category), never on which other models are
present, so adding models to a category never moves existing ones between splits.
"""

from __future__ import annotations

import hashlib

from pipeline.core.schema import SPLITS

DEFAULT_FRACTIONS = (0.8, 0.1, 0.1)


def unit_hash(text: str) -> float:
    """A number in [0, 1) from the sha256 of ``text`` (first 8 bytes, big-endian)."""
    digest = hashlib.sha256(text.encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2.0**64


def split_of(category: str, model_id: str, fractions: tuple[float, float, float] = DEFAULT_FRACTIONS) -> str:
    """The split ("train", "val" or "test") of one model.

    The category is part of the hashed text so that procedural models, whose ids repeat across
    categories ("00000", "00001", ...), are not assigned identically in every category.
    """
    if len(fractions) != 3 or any(f < 0 for f in fractions) or sum(fractions) <= 0:
        raise ValueError(f"split fractions must be three non-negative numbers, got {fractions!r}")
    total = float(sum(fractions))
    x = unit_hash(f"{category}/{model_id}")
    edge = 0.0
    for name, frac in zip(SPLITS, fractions):
        edge += frac / total
        if x < edge:
            return name
    return SPLITS[-1]  # only reachable through float rounding at x close to 1
