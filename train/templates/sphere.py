"""Built-in sphere templates: a cube with each face split n×n, projected to the unit sphere.

n = 2 gives 24 patches, 26 corner points + 48 curves × 2 interior points = 122 points = 366
parameters; n = 3 gives 54 patches and 816 parameters (the paper's two sphere templates).
Each edge becomes the cubic that approximates its great-circle arc (handle length
4/3·tan(θ/4)), so every patch starts close to the sphere.
"""

from __future__ import annotations

import math

import numpy as np

from train.templates.template import Curve, FreePoint, Patch, Template


def _arc_handles(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    theta = math.acos(float(np.clip(a @ b, -1.0, 1.0)))
    k = 4.0 / 3.0 * math.tan(theta / 4.0)
    ta = b - (a @ b) * a
    tb = a - (a @ b) * b
    ta /= np.linalg.norm(ta)
    tb /= np.linalg.norm(tb)
    return a + k * ta, b + k * tb


def sphere_template(n: int) -> Template:
    """Cube-sphere template with 6·n² patches, outward normals, symmetric across x = 0."""
    eye = np.eye(3, dtype=np.int64)
    corner_ids: dict[tuple[int, int, int], int] = {}
    points: list[FreePoint] = []
    curves: list[Curve] = []
    curve_ids: dict[tuple[int, int], int] = {}
    patches: list[Patch] = []

    def corner(key: tuple[int, int, int]) -> int:
        if key not in corner_ids:
            v = np.array(key, dtype=np.float64)
            corner_ids[key] = len(points)
            points.append(FreePoint(tuple((v / np.linalg.norm(v)).tolist())))
        return corner_ids[key]

    def curve(a: int, b: int) -> tuple[int, bool]:
        """Curve id from point a to point b; reversed flag if stored the other way."""
        if (b, a) in curve_ids:
            return curve_ids[(b, a)], True
        if (a, b) not in curve_ids:
            pa, pb = np.array(points[a].xyz), np.array(points[b].xyz)
            ha, hb = _arc_handles(pa, pb)
            i1 = len(points)
            points.extend([FreePoint(tuple(ha.tolist())), FreePoint(tuple(hb.tolist()))])
            curve_ids[(a, b)] = len(curves)
            curves.append(Curve(points=(a, i1, i1 + 1, b)))
        return curve_ids[(a, b)], False

    faces = ("+x", "-x", "+y", "-y", "+z", "-z")
    for axis in range(3):
        for sign in (1, -1):
            normal = sign * eye[axis]
            u, v = eye[(axis + 1) % 3], eye[(axis + 2) % 3]
            if sign < 0:
                u, v = v, u  # keep u × v = outward normal
            for j in range(n):
                for i in range(n):
                    key = lambda ii, jj: tuple(int(x) for x in n * normal + (2 * ii - n) * u + (2 * jj - n) * v)
                    p00, p10, p11, p01 = (
                        corner(key(i, j)),
                        corner(key(i + 1, j)),
                        corner(key(i + 1, j + 1)),
                        corner(key(i, j + 1)),
                    )
                    cs = [curve(p00, p10), curve(p10, p11), curve(p11, p01), curve(p01, p00)]
                    label = faces[2 * axis + (0 if sign > 0 else 1)]
                    patches.append(Patch(tuple(c for c, _ in cs), tuple(r for _, r in cs), label))
    tpl = Template(
        points=points,
        curves=curves,
        patches=patches,
        name=f"sphere{6 * n * n}",
        metadata={"kind": "sphere", "subdivisions": n},
    )
    return tpl.with_symmetry(plane_x=0.0, tol=1e-6)


def sphere24() -> Template:
    return sphere_template(2)


def sphere54() -> Template:
    return sphere_template(3)
