"""Guns (rifles and pistols): barrel (muzzle at -z), receiver, grip, trigger guard, optional
magazine, stock and scope."""

from __future__ import annotations

import numpy as np

from pipeline.shapes import primitives as pr
from pipeline.shapes.model import Part, make_part


def build(rng: np.random.Generator, detached: bool = False) -> list[Part]:
    rifle = rng.random() < 0.65
    scale = rng.uniform(0.8, 1.0) if rifle else rng.uniform(0.45, 0.6)
    rec_len = scale * (rng.uniform(0.45, 0.7) if rifle else rng.uniform(0.7, 0.9))
    rec_h = scale * rng.uniform(0.09, 0.14) * (1.0 if rifle else 1.1)
    rec_w = rec_h * rng.uniform(0.3, 0.45)
    parts = [
        make_part(
            "receiver", pr.superquadric((rec_w, rec_h / 2, rec_len / 2), (0, 0, 0), rng.uniform(5.0, 10.0), k=24, n=10)
        )
    ]

    barrel_len = scale * (rng.uniform(0.5, 0.9) if rifle else rng.uniform(0.03, 0.1))
    barrel_r = rec_h * rng.uniform(0.12, 0.22)
    by = rec_h * rng.uniform(0.05, 0.25)
    parts.append(
        make_part(
            "barrel",
            pr.cylinder(
                barrel_r, barrel_len + 0.04, k=24, center=(0, by, -rec_len / 2 - barrel_len / 2 + 0.02), axis="z"
            ),
        )
    )
    if rifle and rng.random() < 0.6:  # handguard around the rear part of the barrel
        hg_len = barrel_len * rng.uniform(0.35, 0.6)
        hg = pr.superquadric(
            (rec_w * 0.85, rec_h * 0.35, hg_len / 2),
            (0, by - rec_h * 0.05, -rec_len / 2 - hg_len / 2 + 0.02),
            4.0,
            k=24,
            n=8,
        )
        parts.append(make_part("handguard", hg))

    # Grip: rounded box, tilted back, below the rear of the receiver.
    grip_len = scale * rng.uniform(0.2, 0.3) * (1.0 if rifle else 1.4)
    tilt = rng.uniform(10.0, 28.0)
    grip = pr.superquadric((rec_w * 0.9, grip_len / 2, rec_h * 0.35), (0, -grip_len / 2, 0), 6.0, k=20, n=10)
    grip_z = rec_len * rng.uniform(0.15, 0.35)
    parts.append(make_part("grip", pr.transform(grip, pr.rot_x(-tilt), (0, -rec_h * 0.3, grip_z))))

    # Trigger guard: a loop in the x = 0 plane in front of the grip.
    gr = rec_h * rng.uniform(0.3, 0.45)
    a = np.linspace(0.0, np.pi, 18)
    gz = grip_z - gr * 1.1
    path = np.stack([np.zeros_like(a), -rec_h * 0.35 - gr * 0.9 * np.sin(a), gz + gr * np.cos(a)], axis=1)
    parts.append(make_part("trigger_guard", pr.tube(path, rec_h * 0.05, k=10)))

    if rng.random() < (0.7 if rifle else 0.2):  # magazine in front of the guard, optionally curved
        mag_len = scale * rng.uniform(0.15, 0.3)
        curve = rng.uniform(-25.0, 5.0)
        mag = pr.superquadric((rec_w * 0.7, mag_len / 2, rec_h * 0.3), (0, -mag_len / 2, 0), 8.0, k=16, n=10)
        parts.append(
            make_part("magazine", pr.transform(mag, pr.rot_x(curve), (0, -rec_h * 0.3, gz - gr * 1.6 - rec_h * 0.2)))
        )

    if rifle and rng.random() < 0.85:  # stock: lofted, growing taller and dropping toward the butt
        stock_len = scale * rng.uniform(0.35, 0.55)
        drop = rec_h * rng.uniform(0.0, 0.8)
        z = np.linspace(0.0, stock_len, 10)
        f = z / stock_len
        h = rec_h * (0.5 + rng.uniform(0.4, 1.0) * f)
        rings = [
            pr.ring(
                (0, -drop * f[i] - rec_h * 0.05, rec_len / 2 - 0.03 + z[i]),
                pr.X,
                pr.Y,
                pr.superellipse(rec_w * 0.8, h[i] / 2, 24, 5.0),
            )
            for i in range(len(z))
        ]
        parts.append(make_part("stock", pr.loft(rings)))

    if rng.random() < (0.4 if rifle else 0.1):  # scope on top of the receiver
        sl = rec_len * rng.uniform(0.7, 1.1)
        sr = rec_h * rng.uniform(0.15, 0.25)
        prof = [
            (sr * 1.5, -sl / 2),
            (sr * 1.5, -sl * 0.35),
            (sr, -sl * 0.25),
            (sr, sl * 0.25),
            (sr * 1.3, sl * 0.35),
            (sr * 1.3, sl / 2),
        ]
        parts.append(make_part("scope", pr.lathe(prof, k=20, center=(0, rec_h / 2 + sr * 1.8, 0), axis="z")))
    return parts
