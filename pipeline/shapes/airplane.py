"""Airplanes: lofted fuselage (nose at -z), swept tapered wings, tailplane, fin, optional engines
(detached: on pylons, a gap between pylon and nacelle)."""

from __future__ import annotations

import numpy as np

from pipeline.shapes import primitives as pr
from pipeline.shapes.model import Part, make_part, mirrored_pair

GAP = 0.035  # detached engines: clearance between pylon and nacelle, in fuselage lengths


def _fuselage(
    length: float, radius: float, nose: float, tail: float, upsweep: float, k: int = 24, n: int = 28
) -> pr.Mesh:
    t = np.linspace(0.0, 1.0, n)
    r = np.ones(n)
    front = t < nose
    r[front] = np.sqrt(np.clip(1 - ((nose - t[front]) / nose) ** 2, 0, 1)) * 0.97 + 0.03
    back = t > 1 - tail
    s = (t[back] - (1 - tail)) / tail
    r[back] = 1 - 0.78 * s**1.3
    lift = np.where(back, upsweep * radius * ((t - (1 - tail)) / tail).clip(0) ** 1.5, 0.0)
    z = -length / 2 + t * length
    section = pr.superellipse(1.0, 1.0, k)
    rings = [pr.ring((0, ly, zz), pr.X, pr.Y, section * radius * rr) for zz, rr, ly in zip(z, r, lift)]
    return pr.loft(rings)


def _wing(
    root_le: np.ndarray,
    span: float,
    root_chord: float,
    taper: float,
    sweep_deg: float,
    dihedral_deg: float,
    thickness: float,
    n: int = 8,
    k: int = 20,
) -> pr.Mesh:
    """Right half-wing along +x from ``root_le`` (the root's leading edge), chord along +z."""
    foil = pr.airfoil(1.0, thickness, k)
    rings = []
    for x in np.linspace(0.0, span, n):
        f = x / span
        chord = root_chord * (1 - (1 - taper) * f)
        le = root_le + np.array([x, x * np.tan(np.radians(dihedral_deg)), x * np.tan(np.radians(sweep_deg))])
        rings.append(pr.ring(le, pr.Z, pr.Y, foil * chord))
    return pr.loft(rings)


def _fin(
    root_le: np.ndarray,
    height: float,
    root_chord: float,
    taper: float,
    sweep_deg: float,
    thickness: float,
    n: int = 6,
    k: int = 20,
) -> pr.Mesh:
    """Vertical tail in the x = 0 plane, rising along +y."""
    foil = pr.airfoil(1.0, thickness, k)[:, ::-1]  # (thickness -> x, chord -> z)
    rings = []
    for y in np.linspace(0.0, height, n):
        f = y / height
        chord = root_chord * (1 - (1 - taper) * f)
        le = root_le + np.array([0.0, y, y * np.tan(np.radians(sweep_deg))])
        rings.append(pr.ring(le, pr.X, pr.Z, foil * chord))
    return pr.loft(rings)


def _nacelle(center: np.ndarray, length: float, radius: float, k: int = 20) -> pr.Mesh:
    zs = np.linspace(-length / 2, length / 2, 8)
    prof = radius * np.array([0.82, 0.97, 1.0, 1.0, 0.97, 0.9, 0.78, 0.6])
    return pr.lathe(list(zip(prof, zs)), k=k, center=tuple(center), axis="z")


def build(rng: np.random.Generator, detached: bool = False) -> list[Part]:
    L = rng.uniform(1.3, 1.7)
    R = L * rng.uniform(0.045, 0.075)
    parts = [
        make_part("fuselage", _fuselage(L, R, rng.uniform(0.08, 0.18), rng.uniform(0.2, 0.35), rng.uniform(0.2, 0.8)))
    ]

    # Wings: low or high mounted, swept, tapered, with dihedral.
    span = L * rng.uniform(0.4, 0.62)
    root_chord = L * rng.uniform(0.16, 0.3)
    taper = rng.uniform(0.2, 0.6)
    sweep = rng.uniform(0.0, 38.0)
    dihedral = rng.uniform(-2.0, 7.0)
    wing_y = R * rng.choice([-0.55, 0.0, 0.6])
    wing_z = -L * rng.uniform(0.0, 0.12) - root_chord * 0.3
    root_le = np.array([0.0, wing_y, wing_z])
    parts += mirrored_pair("wing", _wing(root_le, span, root_chord, taper, sweep, dihedral, rng.uniform(0.08, 0.14)))

    # Tail: fin at x = 0, tailplane either at the fuselage (conventional) or on top of the fin (T-tail).
    fin_h = L * rng.uniform(0.12, 0.2)
    fin_chord = L * rng.uniform(0.1, 0.16)
    fin_sweep = rng.uniform(25.0, 50.0)
    fin_le = np.array([0.0, R * 0.5, L / 2 - fin_chord * 1.05 - 0.02 * L])
    parts.append(make_part("vertical_tail", _fin(fin_le, fin_h, fin_chord, rng.uniform(0.35, 0.7), fin_sweep, 0.1)))
    t_tail = rng.random() < 0.25
    hs_span = span * rng.uniform(0.25, 0.4)
    hs_chord = fin_chord * rng.uniform(0.7, 1.0)
    if t_tail:
        hs_le = fin_le + np.array([0.0, fin_h * 0.95, fin_h * np.tan(np.radians(fin_sweep))])
    else:
        hs_le = np.array([0.0, R * 0.3, L / 2 - hs_chord * 1.1 - 0.02 * L])
    parts += mirrored_pair(
        "horizontal_tail",
        _wing(
            hs_le, hs_span, hs_chord, rng.uniform(0.4, 0.7), rng.uniform(10.0, 35.0), rng.uniform(0.0, 6.0), 0.09, n=5
        ),
    )

    # Engines under the wings: 0, 2 or 4.
    n_eng = int(rng.choice([0, 2, 4], p=[0.25, 0.55, 0.2]))
    if detached:
        n_eng = max(n_eng, 2)
    eng_r = R * rng.uniform(0.35, 0.55)
    eng_len = root_chord * rng.uniform(0.6, 0.9)
    stations = {0: [], 2: [rng.uniform(0.28, 0.4)], 4: [rng.uniform(0.22, 0.3), rng.uniform(0.5, 0.62)]}[n_eng]
    for j, f in enumerate(stations):
        x = span * f
        le_z = wing_z + x * np.tan(np.radians(sweep))
        y_wing = wing_y + x * np.tan(np.radians(dihedral))
        if detached:
            # pylon hanging from the wing, the nacelle a gap below it (separately modelled parts)
            drop = eng_r * 0.8
            pylon = pr.superquadric(
                (eng_r * 0.12, drop / 2 + eng_r * 0.1, eng_len * 0.3),
                (x, y_wing - drop / 2, le_z + eng_len * 0.05),
                6.0,
                k=12,
                n=6,
            )
            parts += mirrored_pair(f"pylon{j}", pylon)
            y = y_wing - drop - GAP * L - eng_r
        else:
            y = y_wing - eng_r * 1.05
        center = np.array([x, y, le_z - eng_len * 0.2])
        parts += mirrored_pair(f"engine{j}", _nacelle(center, eng_len, eng_r))
    return parts
