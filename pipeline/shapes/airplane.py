"""Airplanes: lofted fuselage (nose at -z), swept tapered wings, tailplane, fin, optional engines
(detached: on pylons, a gap between pylon and nacelle)."""

from __future__ import annotations

import numpy as np

from pipeline.shapes import primitives as pr
from pipeline.shapes.model import Part, make_part, mirrored_pair

GAP = 0.035  # detached engines: clearance between pylon and nacelle, in fuselage lengths
FIGHTER_FRACTION = 0.2  # swept-wing fighters with their engines inside


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
    # Every number is drawn before any mesh is built, in the order the airliners always drew them,
    # so the fighters (drawn last) leave every other airplane as it was.
    L = rng.uniform(1.3, 1.7)
    R = L * rng.uniform(0.045, 0.075)
    nose, tail, upsweep = rng.uniform(0.08, 0.18), rng.uniform(0.2, 0.35), rng.uniform(0.2, 0.8)
    # Wings: low or high mounted, swept, tapered, with dihedral.
    span = L * rng.uniform(0.4, 0.62)
    root_chord = L * rng.uniform(0.16, 0.3)
    taper = rng.uniform(0.2, 0.6)
    sweep = rng.uniform(0.0, 38.0)
    dihedral = rng.uniform(-2.0, 7.0)
    wing_y = R * rng.choice([-0.55, 0.0, 0.6])
    wing_z = -L * rng.uniform(0.0, 0.12) - root_chord * 0.3
    wing_t = rng.uniform(0.08, 0.14)
    # Tail: fin at x = 0, tailplane either at the fuselage (conventional) or on top of the fin (T-tail).
    fin_h = L * rng.uniform(0.12, 0.2)
    fin_chord = L * rng.uniform(0.1, 0.16)
    fin_sweep = rng.uniform(25.0, 50.0)
    fin_taper = rng.uniform(0.35, 0.7)
    t_tail = rng.random() < 0.25
    hs_span = span * rng.uniform(0.25, 0.4)
    hs_chord = fin_chord * rng.uniform(0.7, 1.0)
    hs_taper, hs_sweep, hs_dihedral = rng.uniform(0.4, 0.7), rng.uniform(10.0, 35.0), rng.uniform(0.0, 6.0)
    # Engines under the wings: 0, 2 or 4.
    n_eng = int(rng.choice([0, 2, 4], p=[0.25, 0.55, 0.2]))
    if detached:
        n_eng = max(n_eng, 2)
    eng_r = R * rng.uniform(0.35, 0.55)
    eng_len = root_chord * rng.uniform(0.6, 0.9)
    stations = {0: [], 2: [rng.uniform(0.28, 0.4)], 4: [rng.uniform(0.22, 0.3), rng.uniform(0.5, 0.62)]}[n_eng]
    if rng.random() < FIGHTER_FRACTION:
        # Fighters (GL-117-like): a long pointed nose, thin short-span wings swept far back at
        # mid height, a swept fin and a small tailplane at the fuselage, engines inside.
        R = L * rng.uniform(0.05, 0.075)
        nose, tail, upsweep = rng.uniform(0.2, 0.32), rng.uniform(0.12, 0.22), rng.uniform(0.0, 0.3)
        span = L * rng.uniform(0.28, 0.42)
        root_chord = L * rng.uniform(0.32, 0.48)
        taper = rng.uniform(0.08, 0.3)
        # a delta-like planform: the leading edge swept so that the trailing edge is about straight
        sweep = float(np.degrees(np.arctan(root_chord * (1 - taper) * rng.uniform(0.8, 1.1) / span)))
        dihedral = rng.uniform(-5.0, 1.0)
        wing_y = 0.0
        wing_t = rng.uniform(0.04, 0.07)
        fin_h = L * rng.uniform(0.12, 0.18)
        fin_chord = L * rng.uniform(0.12, 0.2)
        fin_sweep = rng.uniform(40.0, 58.0)
        t_tail = False
        hs_span = span * rng.uniform(0.4, 0.6)
        hs_chord = fin_chord * rng.uniform(0.8, 1.1)
        # the wing's root ends just ahead of the tailplane's
        wing_z = L / 2 - 0.02 * L - hs_chord * 1.15 - root_chord - L * rng.uniform(0.0, 0.05)
        hs_sweep, hs_dihedral = rng.uniform(30.0, 50.0), rng.uniform(-4.0, 0.0)
        eng_len = root_chord * rng.uniform(0.4, 0.6)
        # attached: engines inside; detached: one pair of stores out on the short wing, where they
        # clear the fuselage (at an airliner's inner stations they would touch it and prepare as one body)
        stations = [0.6] if detached else []

    parts = [make_part("fuselage", _fuselage(L, R, nose, tail, upsweep))]
    root_le = np.array([0.0, wing_y, wing_z])
    parts += mirrored_pair("wing", _wing(root_le, span, root_chord, taper, sweep, dihedral, wing_t))
    fin_le = np.array([0.0, R * 0.5, L / 2 - fin_chord * 1.05 - 0.02 * L])
    parts.append(make_part("vertical_tail", _fin(fin_le, fin_h, fin_chord, fin_taper, fin_sweep, 0.1)))
    if t_tail:
        hs_le = fin_le + np.array([0.0, fin_h * 0.95, fin_h * np.tan(np.radians(fin_sweep))])
    else:
        hs_le = np.array([0.0, R * 0.3, L / 2 - hs_chord * 1.1 - 0.02 * L])
    parts += mirrored_pair(
        "horizontal_tail", _wing(hs_le, hs_span, hs_chord, hs_taper, hs_sweep, hs_dihedral, 0.09, n=5)
    )

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
