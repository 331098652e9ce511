"""Guitars standing upright (neck up +y, soundboard facing -z): two-lobed body, neck, head, extras."""

from __future__ import annotations

import numpy as np

from pipeline.shapes import primitives as pr
from pipeline.shapes.model import Part, make_part, mirrored_pair


def _two_lobe_outline(lower_r: float, upper_r: float, gap: float, waist: float, k: int = 128) -> np.ndarray:
    """Star-shaped outline: smooth union of two circles on the y axis, seen from the origin."""
    s, c = pr.sin_cos(k)
    d = np.stack([s, c], axis=1)  # x = sin -> symmetric across x = 0
    centers = [(np.array([0.0, -gap * 0.45]), lower_r), (np.array([0.0, gap * 0.55]), upper_r)]
    hits = []
    for c, r in centers:
        b = d @ c
        hits.append(b + np.sqrt(np.maximum(b**2 - c @ c + r**2, 0.0)))
    h = np.stack(hits)
    # Smooth maximum rounds the waist; a larger ``waist`` sharpens it.
    rad = np.log(np.exp(h * waist).sum(axis=0)) / waist
    return d * rad[:, None]


def build(rng: np.random.Generator, detached: bool = False) -> list[Part]:
    lower = rng.uniform(0.3, 0.42)
    upper = lower * rng.uniform(0.65, 0.9)
    gap = lower * rng.uniform(0.9, 1.3)
    depth = rng.uniform(0.06, 0.14)
    outline = _two_lobe_outline(lower, upper, gap, rng.uniform(12.0, 30.0))
    top = outline[:, 1].max()
    parts = [make_part("body", pr.extrude(outline, depth, axis="z"))]

    neck_len = rng.uniform(0.75, 1.0)
    neck_w = rng.uniform(0.045, 0.065)
    neck = pr.superquadric(
        (neck_w, neck_len / 2, depth * 0.3), (0, top - 0.05 + neck_len / 2, -depth * 0.05), 6.0, k=24, n=24
    )
    parts.append(make_part("neck", neck))

    head_len = rng.uniform(0.14, 0.24)
    head_w = neck_w * rng.uniform(1.3, 1.9)
    tilt = rng.uniform(0.0, 15.0)
    head_y = top - 0.05 + neck_len
    head = pr.superquadric(
        (head_w, head_len / 2, depth * 0.12), (0, head_len / 2 - 0.01, 0), rng.uniform(4.0, 10.0), k=16, n=8
    )
    head = pr.transform(head, pr.rot_x(-tilt), (0, head_y, -depth * 0.05))
    parts.append(make_part("head", head))

    if rng.random() < 0.6:  # bridge on the soundboard
        bw = lower * rng.uniform(0.35, 0.6)
        bridge = pr.superquadric((bw / 2, 0.02, 0.012), (0, -gap * 0.45, -depth / 2), 6.0, k=16, n=6)
        parts.append(make_part("bridge", bridge))
    if rng.random() < 0.5:  # tuning pegs, mirrored pairs along the head
        n_pegs = int(rng.integers(2, 4))
        for j in range(n_pegs):
            y = head_y + head_len * (0.25 + 0.5 * j / max(n_pegs - 1, 1)) * np.cos(np.radians(tilt))
            z = -depth * 0.05 + head_len * (0.25 + 0.5 * j / max(n_pegs - 1, 1)) * np.sin(np.radians(tilt))
            peg = pr.cylinder(0.012, head_w * 0.8, k=12, center=(head_w + head_w * 0.3, y, z), axis="x")
            parts += mirrored_pair(f"peg{j}", peg)
    return parts
