"""Knives: pointed tapered blade (tip at -z, edge down), optional guard, handle, optional pommel."""

from __future__ import annotations

import numpy as np

from pipeline.shapes import primitives as pr
from pipeline.shapes.model import Part, make_part


def _blade(
    length: float, height: float, thick: float, spine_drop: float, belly: float, k: int = 24, n: int = 28
) -> pr.Mesh:
    """Stations from the root (z = 0) to the tip (z = -length); sections thin in x, tall in y."""
    t = np.linspace(0.0, 1.0, n)  # 0 root, 1 tip
    # Spine and edge meet at the tip, whose height sets a drop-point (low) or clip-point look.
    tip_y = height * (1 - spine_drop)
    spine = height - (height - tip_y) * np.clip((t - 0.55) / 0.45, 0, 1) ** 2
    edge = tip_y * np.clip((t - 0.35) / 0.65, 0, 1) ** belly
    top = spine
    bottom = np.minimum(edge, top - 2e-3)
    rings = []
    for z, lo, hi, tt in zip(-t * length, bottom, top, t):
        half_h = max((hi - lo) / 2, 1e-3)
        w = thick * (1 - 0.7 * tt) / 2 + 1e-4
        sec = pr.superellipse(w, half_h, k, 1.3)  # pointed top/bottom: a sharp edge
        rings.append(pr.ring((0, (hi + lo) / 2, z), pr.X, pr.Y, sec))
    return pr.loft(rings)


def build(rng: np.random.Generator, detached: bool = False) -> list[Part]:
    blade_len = rng.uniform(0.6, 1.1)
    blade_h = blade_len * rng.uniform(0.12, 0.25)
    blade = _blade(blade_len, blade_h, rng.uniform(0.015, 0.03), rng.uniform(0.3, 0.9), rng.uniform(1.5, 3.5))
    parts = [make_part("blade", pr.transform(blade, None, (0, -blade_h * 0.5, 0)))]

    handle_len = blade_len * rng.uniform(0.45, 0.7)
    hh = blade_h * rng.uniform(0.55, 0.9) / 2
    hw = hh * rng.uniform(0.5, 0.8)
    z = np.linspace(0.0, handle_len, 12)
    swell = 1 + rng.uniform(0.0, 0.2) * np.sin(np.pi * z / handle_len)
    end = np.sqrt(np.clip(np.minimum(z + 0.02, handle_len - z + 0.02) / 0.04, 0.3, 1.0))
    rings = [
        pr.ring((0, 0, zz), pr.X, pr.Y, pr.superellipse(hw * s * e, hh * s * e, 32, 3.0))
        for zz, s, e in zip(z - 0.01, swell, end)
    ]
    parts.append(make_part("handle", pr.loft(rings)))

    if rng.random() < 0.6:
        gh = blade_h * rng.uniform(0.35, 0.7)
        guard = pr.superquadric(
            (hw * rng.uniform(1.2, 1.8), gh, 0.015), (0, -blade_h * 0.5 + blade_h * 0.5 * 0.0, 0.0), 6.0, k=20, n=8
        )
        parts.append(make_part("guard", guard))
    if rng.random() < 0.4:
        pr_ = hh * rng.uniform(0.9, 1.3)
        parts.append(
            make_part("pommel", pr.superquadric((pr_ * 0.8, pr_, pr_ * 0.8), (0, 0, handle_len), 2.5, k=20, n=10))
        )
    return parts
