"""Cars: lofted body (front at -z), cabin/greenhouse, four wheels (detached: clear of the body), optional spoiler."""

from __future__ import annotations

import numpy as np

from pipeline.shapes import primitives as pr
from pipeline.shapes.model import Part, make_part, mirrored_pair

GAP = 0.045  # detached wheels: clearance to the body, in car lengths


def _body(
    length: float,
    width: float,
    bottom: float,
    height: float,
    hood_drop: float,
    tail_drop: float,
    exponent: float,
    k: int = 32,
    n: int = 22,
) -> pr.Mesh:
    t = np.linspace(0.0, 1.0, n)
    # Top line: lower at the nose (hood slope) and slightly lower at the tail; rounded ends.
    top = height * (1 - hood_drop * np.clip(1 - t / 0.3, 0, 1) ** 2 - tail_drop * np.clip((t - 0.8) / 0.2, 0, 1) ** 2)
    end = np.clip(np.minimum(t, 1 - t) / 0.06, 0, 1)
    round_ = 0.8 + 0.2 * np.sqrt(end)
    rings = []
    for tt, tp, rr in zip(t, top, round_):
        half_h = (tp * rr) / 2
        section = pr.superellipse(width / 2 * rr, half_h, k, exponent)
        rings.append(pr.ring((0, bottom + half_h + (1 - rr) * 0.02, -length / 2 + tt * length), pr.X, pr.Y, section))
    return pr.loft(rings)


def _cabin(
    z0: float,
    z1: float,
    base_y: float,
    height: float,
    width: float,
    rake_front: float,
    rake_back: float,
    k: int = 32,
    n: int = 6,
) -> pr.Mesh:
    """Greenhouse: rounded-rectangle rings in xz stacked along y, shrinking toward the roof."""
    rings = []
    for f in np.linspace(0.0, 1.0, n):
        y = base_y + f * height
        front = z0 + rake_front * f**0.8
        back = z1 - rake_back * f**0.8
        w = width * (1 - 0.18 * f**2)
        sec = pr.superellipse(w / 2, (back - front) / 2, k, 6.0)
        rings.append(pr.ring((0, y, (front + back) / 2), pr.X, pr.Z, sec))
    return pr.loft(rings)


def build(rng: np.random.Generator, detached: bool = False) -> list[Part]:
    L = rng.uniform(1.6, 2.0)
    W = L * rng.uniform(0.38, 0.46)
    kind = rng.choice(["sedan", "hatch", "suv", "sports"])
    wheel_r = L * rng.uniform(0.085, 0.11) * (1.15 if kind == "suv" else 1.0)
    bottom = wheel_r * rng.uniform(0.45, 0.7)
    body_h = L * {"sedan": 0.16, "hatch": 0.17, "suv": 0.2, "sports": 0.13}[kind] * rng.uniform(0.9, 1.1)
    body = _body(L, W, bottom, body_h, rng.uniform(0.1, 0.35), rng.uniform(0.0, 0.2), rng.uniform(4.0, 8.0))
    parts = [make_part("body", body)]

    top_y = bottom + body_h * 0.95
    cab_h = L * {"sedan": 0.13, "hatch": 0.14, "suv": 0.17, "sports": 0.09}[kind] * rng.uniform(0.85, 1.1)
    start = {"sedan": 0.32, "hatch": 0.3, "suv": 0.27, "sports": 0.38}[kind] + rng.uniform(-0.04, 0.04)
    end = {"sedan": 0.78, "hatch": 0.93, "suv": 0.95, "sports": 0.8}[kind] + rng.uniform(-0.04, 0.02)
    z0, z1 = -L / 2 + start * L, -L / 2 + end * L
    rake_f = (z1 - z0) * rng.uniform(0.2, 0.35)
    rake_b = (z1 - z0) * (rng.uniform(0.05, 0.12) if kind in ("hatch", "suv") else rng.uniform(0.15, 0.3))
    parts.append(make_part("cabin", _cabin(z0, z1, top_y - 0.02, cab_h, W * 0.86, rake_f, rake_b)))

    wheelbase = L * rng.uniform(0.56, 0.66)
    tire_w = W * rng.uniform(0.14, 0.2)
    # Attached: tyres half inside the body's flanks. Detached: clear of the body by a gap (as
    # separately modelled wheels are), wide enough to stay a separate body through the repair.
    x = W / 2 + GAP * L + tire_w / 2 if detached else W / 2 - tire_w * 0.45
    for name, z in (("wheel_front", -wheelbase / 2 - L * 0.02), ("wheel_rear", wheelbase / 2)):
        parts += mirrored_pair(name, pr.cylinder(wheel_r, tire_w, k=28, center=(x, wheel_r, z), axis="x"))

    if rng.random() < 0.3:  # rear wing on two struts
        sz = L / 2 - L * 0.06
        sy = bottom + body_h + L * 0.05
        parts.append(
            make_part("spoiler", pr.superquadric((W * 0.45, L * 0.008, L * 0.04), (0, sy, sz), 8.0, k=24, n=8))
        )
        strut = pr.superquadric((L * 0.008, L * 0.03, L * 0.015), (W * 0.3, sy - L * 0.03, sz), 6.0, k=12, n=6)
        parts += mirrored_pair("spoiler_strut", strut)
    return parts
