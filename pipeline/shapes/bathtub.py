"""Bathtubs: a hollow tub shell (basin open at the top), optional feet, optional faucet.

Long axis along x; the faucet (if any) sits on the back rim (+z) at x = 0 to keep the symmetry.
"""

from __future__ import annotations

import numpy as np

from pipeline.shapes import primitives as pr
from pipeline.shapes.model import Part, make_part, mirrored_pair


def build(rng: np.random.Generator, detached: bool = False) -> list[Part]:
    Lx = rng.uniform(0.75, 1.0)  # half length
    Wz = Lx * rng.uniform(0.38, 0.55)  # half width
    H = rng.uniform(0.35, 0.55)
    wall = rng.uniform(0.04, 0.09)
    floor = rng.uniform(0.05, 0.1)
    exponent = rng.uniform(3.0, 10.0)
    taper = rng.uniform(0.75, 1.0)  # bottom ring scale
    feet = rng.random() < 0.4
    base = H * rng.uniform(0.12, 0.2) if feet else 0.0
    k = 96
    rim_flare = rng.uniform(1.0, 1.06)

    def rect(sx: float, sz: float, y: float) -> np.ndarray:
        return pr.ring((0, base + y, 0), pr.X, pr.Z, pr.superellipse(sx, sz, k, exponent))

    rings = [
        rect(Lx * taper, Wz * taper, 0.0),
        rect(Lx * (taper + 1) / 2, Wz * (taper + 1) / 2, H * 0.5),
        rect(Lx * rim_flare, Wz * rim_flare, H * 0.97),
        rect(Lx * rim_flare, Wz * rim_flare, H),
        rect(Lx * rim_flare - wall * 0.3, Wz * rim_flare - wall * 0.3, H + wall * 0.15),
        rect(Lx - wall * 0.8, Wz - wall * 0.8, H + wall * 0.05),
        rect(Lx - wall, Wz - wall, H - wall * 0.3),
        rect((Lx - wall) * (taper + 1) / 2, (Wz - wall) * (taper + 1) / 2, H * 0.5),
        rect((Lx - wall) * taper * 0.97, (Wz - wall) * taper * 0.97, floor),
    ]
    parts = [make_part("tub", pr.loft(rings))]

    if feet:
        fr = base * rng.uniform(0.55, 0.8)
        for name, sx in (("foot_front", -1.0), ("foot_back", 1.0)):
            c = (Lx * taper * 0.75, base * 0.55, sx * Wz * taper * 0.7)
            parts += mirrored_pair(name, pr.superquadric((fr, base * 0.6, fr), c, 2.0, k=16, n=8))
    if rng.random() < 0.35:  # faucet: a bent tube rising from the back rim and curving over the basin
        r = rng.uniform(0.015, 0.03)
        a = np.linspace(0, np.pi * 0.85, 14)
        rise = rng.uniform(0.08, 0.18)
        bend = rng.uniform(0.05, 0.1)
        path = np.stack(
            [
                np.zeros_like(a),
                base + H - 0.02 + rise * np.sin(np.clip(a * 1.6, 0, np.pi / 2)) + bend * np.sin(a) * 0.5,
                Wz - wall * 0.5 - bend * (1 - np.cos(a)),
            ],
            axis=1,
        )
        parts.append(make_part("faucet", pr.tube(path, r, k=12)))
    return parts
