"""Cars: lofted body (front at -z), cabin/greenhouse, four wheels (detached: clear of the body), optional spoiler."""

from __future__ import annotations

import numpy as np

from pipeline.shapes import primitives as pr
from pipeline.shapes.model import Part, make_part, mirrored_pair

GAP = 0.045  # detached wheels: clearance to the body, in car lengths
RACE_FRACTION = 0.2  # low, wide race bodies with flared arches and a wing


def _body(
    length: float,
    width: float,
    bottom: float,
    height: float,
    hood_drop: float,
    tail_drop: float,
    exponent: float,
    flare: float = 0.0,
    arches: tuple[float, ...] = (),
    arch_r: float = 0.0,
    k: int = 32,
    n: int = 22,
) -> pr.Mesh:
    t = np.linspace(0.0, 1.0, n)
    # Top line: lower at the nose (hood slope) and slightly lower at the tail; rounded ends.
    top = height * (1 - hood_drop * np.clip(1 - t / 0.3, 0, 1) ** 2 - tail_drop * np.clip((t - 0.8) / 0.2, 0, 1) ** 2)
    end = np.clip(np.minimum(t, 1 - t) / 0.06, 0, 1)
    round_ = 0.8 + 0.2 * np.sqrt(end)
    z = -length / 2 + t * length
    # Flared arches: the body widens over each wheel (a Gaussian bump along z).
    widen = 1 + flare * sum((np.exp(-(((z - a) / (1.2 * arch_r)) ** 2)) for a in arches), np.zeros(n))
    rings = []
    for tt, tp, rr, ww in zip(t, top, round_, widen):
        half_h = (tp * rr) / 2
        section = pr.superellipse(width / 2 * rr * ww, half_h, k, exponent)
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
    # Every number is drawn before any mesh is built, in the order the saloons always drew them,
    # so the race bodies (drawn last) leave every other car as it was.
    L = rng.uniform(1.6, 2.0)
    W = L * rng.uniform(0.38, 0.46)
    kind = rng.choice(["sedan", "hatch", "suv", "sports"])
    wheel_r = L * rng.uniform(0.085, 0.11) * (1.15 if kind == "suv" else 1.0)
    bottom = wheel_r * rng.uniform(0.45, 0.7)
    body_h = L * {"sedan": 0.16, "hatch": 0.17, "suv": 0.2, "sports": 0.13}[kind] * rng.uniform(0.9, 1.1)
    hood_drop, tail_drop, exponent = rng.uniform(0.1, 0.35), rng.uniform(0.0, 0.2), rng.uniform(4.0, 8.0)
    cab_h = L * {"sedan": 0.13, "hatch": 0.14, "suv": 0.17, "sports": 0.09}[kind] * rng.uniform(0.85, 1.1)
    start = {"sedan": 0.32, "hatch": 0.3, "suv": 0.27, "sports": 0.38}[kind] + rng.uniform(-0.04, 0.04)
    end = {"sedan": 0.78, "hatch": 0.93, "suv": 0.95, "sports": 0.8}[kind] + rng.uniform(-0.04, 0.02)
    rake_f_frac = rng.uniform(0.2, 0.35)
    rake_b_frac = rng.uniform(0.05, 0.12) if kind in ("hatch", "suv") else rng.uniform(0.15, 0.3)
    wheelbase = L * rng.uniform(0.56, 0.66)
    tire_w = W * rng.uniform(0.14, 0.2)
    spoiler = rng.random() < 0.3
    cab_w, flare, wing = 0.86, 0.0, (0.45, 0.04, 0.05)
    if rng.random() < RACE_FRACTION:
        # Race bodies (TORCS-like): low, wide, a short low canopy, flared arches, a large wing.
        W = L * rng.uniform(0.46, 0.54)
        wheel_r *= 0.85  # under the fenders
        body_h = L * rng.uniform(0.125, 0.145)
        bottom = wheel_r * rng.uniform(0.4, 0.55)
        hood_drop, exponent = rng.uniform(0.3, 0.5), rng.uniform(6.0, 10.0)
        cab_h = L * rng.uniform(0.06, 0.085)
        start, end = rng.uniform(0.36, 0.46), rng.uniform(0.66, 0.78)
        cab_w = rng.uniform(0.6, 0.75)
        flare = rng.uniform(0.08, 0.16)
        spoiler = rng.random() < 0.8
        wing = (rng.uniform(0.45, 0.5), rng.uniform(0.05, 0.08), rng.uniform(0.06, 0.1))

    wheel_z = (-wheelbase / 2 - L * 0.02, wheelbase / 2)
    body = _body(L, W, bottom, body_h, hood_drop, tail_drop, exponent, flare=flare, arches=wheel_z, arch_r=wheel_r)
    parts = [make_part("body", body)]
    top_y = bottom + body_h * 0.95
    z0, z1 = -L / 2 + start * L, -L / 2 + end * L
    rake_f, rake_b = (z1 - z0) * rake_f_frac, (z1 - z0) * rake_b_frac
    parts.append(make_part("cabin", _cabin(z0, z1, top_y - 0.02, cab_h, W * cab_w, rake_f, rake_b)))

    # Attached: tyres half inside the body's flanks. Detached: clear of the body by a gap (as
    # separately modelled wheels are), wide enough to stay a separate body through the repair.
    half_w = W / 2 * (1 + flare)  # the body's half-width over the wheels
    x = half_w + GAP * L + tire_w / 2 if detached else half_w - tire_w * 0.45
    for name, z in zip(("wheel_front", "wheel_rear"), wheel_z):
        parts += mirrored_pair(name, pr.cylinder(wheel_r, tire_w, k=28, center=(x, wheel_r, z), axis="x"))

    if spoiler:  # rear wing on two struts
        span, chord, lift = wing
        sz = L / 2 - L * 0.06
        sy = bottom + body_h + L * lift
        parts.append(
            make_part("spoiler", pr.superquadric((W * span, L * 0.008, L * chord), (0, sy, sz), 8.0, k=24, n=8))
        )
        strut = pr.superquadric(
            (L * 0.008, L * (lift - 0.02), L * 0.015), (W * 0.3, sy - L * (lift - 0.02), sz), 6.0, k=12, n=6
        )
        parts += mirrored_pair("spoiler_strut", strut)
    return parts
