"""Closed, outward-oriented triangle-mesh primitives for the procedural shapes.

Almost everything is a *loft*: a sequence of closed rings with the same point count, joined by
quads, with both ends capped by a fan to the ring's centroid. Cylinders, frusta, lathes (revolved
profiles, including hollow cups whose profile goes up the outside and back down the inside),
ellipsoids, superquadric rounded boxes, swept tubes and extruded star-shaped outlines are all
lofts, so each is watertight by construction. Orientation is fixed afterwards from the sign of
the enclosed volume, so callers never have to think about winding.

Ring sampling convention: angle theta_j = 2 pi j / k with the lateral coordinate = a * sin(theta),
so a ring centred on x = 0 is mirror-symmetric across x = 0 (needed for the bilateral symmetry
of the shapes). Use even k for rings swept in the x = 0 plane.
"""

from __future__ import annotations

import numpy as np

Mesh = tuple[np.ndarray, np.ndarray]  # (vertices (n, 3) float64, faces (m, 3) int64)


def angles(k: int) -> np.ndarray:
    return 2.0 * np.pi * np.arange(k) / k


def sin_cos(k: int) -> tuple[np.ndarray, np.ndarray]:
    """sin, cos of ``angles(k)`` made exactly mirror-symmetric (sin[k-j] = -sin[j], cos[k-j] = cos[j])."""
    t = angles(k)
    s, c = np.sin(t), np.cos(t)
    j = np.arange(1, k)
    half = j[j < k - j]
    s[k - half] = -s[half]
    c[k - half] = c[half]
    s[0] = 0.0
    if k % 2 == 0:
        s[k // 2] = 0.0
    return s, c


def superellipse(a: float, b: float, k: int, exponent: float = 2.0) -> np.ndarray:
    """(k, 2) points of |u/a|^e + |v/b|^e = 1; u = a sin(theta)-like, so symmetric in u."""
    s, c = sin_cos(k)
    p = 2.0 / exponent
    return np.stack([a * np.sign(s) * np.abs(s) ** p, b * np.sign(c) * np.abs(c) ** p], axis=1)


def orient_outward(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces reversed if the signed volume is negative (closed mesh assumed)."""
    tri = vertices[faces]
    vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()
    return faces[:, ::-1].copy() if vol < 0 else faces


def loft(rings: list[np.ndarray] | np.ndarray, cap_start: bool = True, cap_end: bool = True) -> Mesh:
    """Join closed rings (n, k, 3) by quads; cap the ends with fans; orient outward."""
    r = np.asarray(rings, np.float64)
    n, k, _ = r.shape
    verts = [r.reshape(-1, 3)]
    idx = np.arange(n * k).reshape(n, k)
    a, b = idx[:-1], np.roll(idx[:-1], -1, axis=1)
    c, d = np.roll(idx[1:], -1, axis=1), idx[1:]
    faces = [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    nxt = n * k
    for use, ring_i, flip in ((cap_start, 0, False), (cap_end, n - 1, True)):
        if not use:
            continue
        verts.append(r[ring_i].mean(axis=0, keepdims=True))
        ring = idx[ring_i]
        fan = np.stack([np.full(k, nxt), np.roll(ring, -1), ring], -1)
        faces.append(fan[:, ::-1] if flip else fan)
        nxt += 1
    v = np.concatenate(verts)
    f = np.concatenate(faces).astype(np.int64)
    return v, orient_outward(v, f)


def ring(center: np.ndarray, u_axis: np.ndarray, v_axis: np.ndarray, pts2d: np.ndarray) -> np.ndarray:
    """Place 2D ring points (k, 2) in the plane spanned by u_axis, v_axis through center."""
    return (
        np.asarray(center, float) + pts2d[:, :1] * np.asarray(u_axis, float) + pts2d[:, 1:] * np.asarray(v_axis, float)
    )


X, Y, Z = np.eye(3)


def lathe(
    profile, k: int = 32, center=(0.0, 0.0, 0.0), axis: str = "y", exponent: float = 2.0, aspect: float = 1.0
) -> Mesh:
    """Revolve a (radius, height) profile around a coordinate axis (y: rings in xz; z: rings in xy).

    ``exponent`` > 2 gives squarish sections, ``aspect`` scales the second in-plane axis.
    """
    u, v, w = (X, Z, Y) if axis == "y" else (X, Y, Z)
    circle = superellipse(1.0, aspect, k, exponent)
    rings = [ring(np.asarray(center) + h * w, u, v, circle * max(rad, 1e-4)) for rad, h in profile]
    return loft(rings)


def cylinder(
    radius: float, length: float, k: int = 32, center=(0, 0, 0), axis: str = "y", radius2: float | None = None
) -> Mesh:
    """Capped cylinder (or frustum when radius2 is given) centred at ``center`` along an axis."""
    r2 = radius if radius2 is None else radius2
    axes = {"x": (Y, Z, X), "y": (X, Z, Y), "z": (X, Y, Z)}
    u, v, w = axes[axis]
    circle = superellipse(1.0, 1.0, k)
    c = np.asarray(center, float)
    return loft([ring(c - w * length / 2, u, v, circle * radius), ring(c + w * length / 2, u, v, circle * r2)])


def superquadric(
    radii, center=(0, 0, 0), exponent: float = 2.0, k: int = 32, n: int = 16, vexp: float | None = None
) -> Mesh:
    """Ellipsoid (exponent 2) or rounded box (exponent ~6-10) with semi-axes ``radii`` (x, y, z).

    Rings lie in xz planes stacked along y; the poles are flat tiny caps (fans).
    """
    rx, ry, rz = radii
    ve = exponent if vexp is None else vexp
    phi = np.linspace(-np.pi / 2, np.pi / 2, n + 2)[1:-1]
    s, c = np.sin(phi), np.cos(phi)
    p = 2.0 / ve
    ys = ry * np.sign(s) * np.abs(s) ** p
    scale = np.abs(c) ** p
    base = superellipse(rx, rz, k, exponent)
    cen = np.asarray(center, float)
    rings = [ring(cen + y * Y, X, Z, base * sc) for y, sc in zip(ys, scale)]
    return loft(rings)


def tube(path: np.ndarray, radius: float | np.ndarray, k: int = 16) -> Mesh:
    """Capped tube of circular section swept along a polyline (parallel-transport frames)."""
    p = np.asarray(path, float)
    rad = np.broadcast_to(np.asarray(radius, float), (len(p),))
    tang = np.gradient(p, axis=0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    # Start with a normal orthogonal to the tangent, preferring +x so x = 0 paths stay symmetric.
    ref = X if abs(tang[0] @ X) < 0.9 else Y
    nrm = ref - (ref @ tang[0]) * tang[0]
    nrm /= np.linalg.norm(nrm)
    circle = superellipse(1.0, 1.0, k)
    rings = []
    for i in range(len(p)):
        nrm = nrm - (nrm @ tang[i]) * tang[i]
        nrm /= np.linalg.norm(nrm)
        bin_ = np.cross(tang[i], nrm)
        rings.append(ring(p[i], nrm, bin_, circle * rad[i]))
    return loft(rings)


def extrude(outline: np.ndarray, depth: float, axis: str = "z", offset: float = 0.0) -> Mesh:
    """Extrude a star-shaped (w.r.t. its centroid) closed 2D outline (k, 2) by ``depth``.

    axis "z": outline in (x, y), extruded along z from offset - depth/2 to offset + depth/2.
    axis "x": outline in (z, y) coordinates, extruded along x (centred, so symmetric across x = 0).
    """
    o = np.asarray(outline, float)
    if axis == "z":
        u, v, w = X, Y, Z
    elif axis == "x":
        u, v, w = Z, Y, X
    else:
        u, v, w = X, Z, Y
    lo = ring(w * (offset - depth / 2), u, v, o)
    hi = ring(w * (offset + depth / 2), u, v, o)
    return loft([lo, hi])


def airfoil(chord: float, thickness: float, k: int = 24) -> np.ndarray:
    """(2k - 2, 2) closed symmetric airfoil ring (along-chord from 0 at the leading edge, thickness)."""
    x = 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, k))
    t = 5 * thickness * (0.2969 * np.sqrt(x) - 0.126 * x - 0.3516 * x**2 + 0.2843 * x**3 - 0.1036 * x**4)
    t[1:-1] = np.maximum(t[1:-1], 1e-4 * thickness)
    t[[0, -1]] = 0.0  # single leading/trailing-edge points lie exactly on the chord line
    upper = np.stack([x * chord, t * chord], 1)
    lower = np.stack([x[1:-1][::-1] * chord, -t[1:-1][::-1] * chord], 1)
    return np.concatenate([upper, lower])


def transform(mesh: Mesh, rotation: np.ndarray | None = None, translation=(0, 0, 0)) -> Mesh:
    v, f = mesh
    if rotation is not None:
        v = v @ np.asarray(rotation).T
        if np.linalg.det(rotation) < 0:
            f = f[:, ::-1].copy()
    return v + np.asarray(translation, float), f


def rot_x(deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
