"""Seeded randomness keyed by what is being made, never by global state, time or process id."""

from __future__ import annotations

import hashlib

import numpy as np


def derive_seed(*key: object) -> int:
    """A 64-bit seed from a key such as (seed, stage, category, model_id, view, variant)."""
    text = "\x1f".join(str(k) for k in key)
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "little")


def rng_for(*key: object) -> np.random.Generator:
    """Independent generator for one (seed, stage, category, model, view, variant) key."""
    return np.random.default_rng(derive_seed(*key))
