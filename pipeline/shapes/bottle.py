"""Bottles: body, shoulder, neck and optional cap (detached: floating above the neck), each a
separate closed solid of revolution."""

from __future__ import annotations

import numpy as np

from pipeline.shapes import primitives as pr
from pipeline.shapes.model import Part, make_part

GAP = 0.03  # detached cap: clearance above the neck, in bottle heights


def build(rng: np.random.Generator, detached: bool = False) -> list[Part]:
    H = rng.uniform(1.4, 2.0)
    R = H * rng.uniform(0.12, 0.22)
    body_h = H * rng.uniform(0.4, 0.65)
    shoulder_h = H * rng.uniform(0.08, 0.22)
    neck_r = R * rng.uniform(0.22, 0.4)
    neck_h = H - body_h - shoulder_h
    exponent = float(rng.choice([2.0, 2.0, 3.0, 5.0]))  # round, or squarish like a spirits bottle
    aspect = 1.0 if exponent == 2.0 else float(rng.uniform(0.6, 1.0))
    k = 40

    # Body: slight bulge or waist, rounded bottom edge.
    bulge = rng.uniform(-0.08, 0.1)
    heel = R * rng.uniform(0.05, 0.2)
    ys = np.concatenate(
        [[0.0], heel * (1 - np.cos(np.linspace(0.2, np.pi / 2, 4))), np.linspace(heel * 1.5, body_h, 8)]
    )
    rs = [R * 0.6]
    for y in ys[1:]:
        if y <= heel:
            rs.append(R - heel + np.sqrt(max(heel**2 - (heel - y) ** 2, 0)))
        else:
            rs.append(R * (1 + bulge * np.sin(np.pi * y / body_h)))
    body = pr.lathe(list(zip(rs, ys)), k=k, exponent=exponent, aspect=aspect)
    parts = [make_part("body", body)]

    # Shoulder: from the body radius to the neck radius along a cosine (or conical) curve.
    f = np.linspace(0.0, 1.0, 9)
    curve = rng.uniform(0.5, 1.5)
    sr = neck_r + (R * (1 + bulge * 0.0) - neck_r) * (0.5 + 0.5 * np.cos(np.pi * f**curve))
    sy = body_h - 0.01 + f * (shoulder_h + 0.02)
    parts.append(make_part("shoulder", pr.lathe(list(zip(sr, sy)), k=k, exponent=exponent, aspect=aspect)))

    # Neck with an optional lip.
    lip = rng.random() < 0.5
    ny = body_h + shoulder_h
    nprof = [(neck_r, ny - 0.01), (neck_r, ny + neck_h * 0.85)]
    nprof += [(neck_r * 1.15, ny + neck_h * 0.88), (neck_r * 1.15, H)] if lip else [(neck_r, H)]
    parts.append(make_part("neck", pr.lathe(nprof, k=32)))

    if rng.random() < 0.6 or detached:
        cap_h = H * rng.uniform(0.05, 0.1)
        cap_r = neck_r * rng.uniform(1.15, 1.35)
        # attached: over the neck's top; detached: floating a gap above it (a separate body)
        cap_y = H + GAP * H + cap_h / 2 if detached else H - cap_h * 0.35
        parts.append(make_part("cap", pr.cylinder(cap_r, cap_h, k=32, center=(0, cap_y, 0), axis="y")))
    return parts
