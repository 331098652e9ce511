"""Mugs: a hollow cup (open top, interior void, solid bottom) and a handle loop on the +z side."""

from __future__ import annotations

import numpy as np

from pipeline.shapes import primitives as pr
from pipeline.shapes.model import Part, make_part


def build(rng: np.random.Generator, detached: bool = False) -> list[Part]:
    H = rng.uniform(0.75, 1.1)
    R_top = rng.uniform(0.3, 0.45)
    R_bot = R_top * rng.uniform(0.75, 1.15)
    wall = rng.uniform(0.03, 0.06)
    floor = rng.uniform(0.04, 0.1)
    bevel = rng.uniform(0.01, 0.06)
    # Profile (radius, height): outside up, over the rim, inside down to the floor.
    outer = [(1e-3, 0.0), (R_bot - bevel, 0.0), (R_bot, bevel)]
    bulge = rng.uniform(-0.04, 0.06)
    for f in (0.35, 0.7):
        outer.append((R_bot + (R_top - R_bot) * f + bulge * np.sin(np.pi * f), H * f))
    outer += [(R_top, H), (R_top - wall, H)]
    inner = [(r - wall, h) for r, h in outer[::-1][2:-2] if h > floor + 0.02]
    profile = outer + inner + [(R_bot - wall - bevel * 0.5, floor), (1e-3, floor)]
    cup = pr.lathe(profile, k=64)
    parts = [make_part("cup", cup)]

    # Handle: tube along an arc in the x = 0 plane, ends buried in the wall.
    y0 = H * rng.uniform(0.15, 0.3)
    y1 = H * rng.uniform(0.7, 0.88)
    reach = rng.uniform(0.14, 0.3)
    tube_r = rng.uniform(0.022, 0.045)
    squareness = rng.uniform(0.3, 1.0)  # 1: round D shape, lower: boxier
    phi = np.linspace(-np.pi / 2, np.pi / 2, 28)
    yc, hy = (y0 + y1) / 2, (y1 - y0) / 2
    c = np.cos(phi)
    s = np.sin(phi)
    ys = yc + hy * np.sign(s) * np.abs(s) ** squareness
    # the cup's outer radius at each height, bulge included: the ends sit deep in the
    # wall, so the handle stays joined to the cup through the watertight repair
    side = np.array(outer[2:-1])
    wall_r = np.interp(ys, side[:, 1], side[:, 0])
    zs = wall_r - 0.8 * wall + (reach + 0.8 * wall) * np.abs(c) ** squareness
    path = np.stack([np.zeros_like(ys), ys, zs], axis=1)
    parts.append(make_part("handle", pr.tube(path, tube_r, k=16)))
    return parts
