"""CPU thumbnails of triangle meshes: a numpy z-buffer rasterizer with Lambert shading.

No GPU, no Blender: used for contact sheets and quick looks at any stage's meshes.

View convention (ShapeNet frame: y up, front along -z): the camera sits on the direction
``(sin(az) cos(el), sin(el), -cos(az) cos(el))`` from the mesh centre, so ``azimuth_deg=0``
looks straight at the front and positive azimuth moves the camera toward +x. The projection is
orthographic and the mesh is auto-fitted (its projected bounding box fills the frame with a
small margin). Pixel convention: (u, v), origin at the top-left corner, pixel i covers [i, i+1).
"""

from __future__ import annotations

import numpy as np

BACKGROUND = 255
DEFAULT_COLOR = (0.78, 0.80, 0.86)
_MARGIN = 0.06  # fraction of the frame left empty on each side
_CHUNK = 1 << 21  # candidate (triangle, pixel) pairs handled at once; bounds memory


def view_basis(azimuth_deg: float, elevation_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera right, down and forward unit vectors (world frame) for the thumbnail view."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    to_cam = np.array([np.sin(az) * np.cos(el), np.sin(el), -np.cos(az) * np.cos(el)])
    forward = -to_cam
    up_world = np.array([0.0, 1.0, 0.0])
    right = np.cross(forward, up_world)
    if np.linalg.norm(right) < 1e-8:  # looking straight up or down: any horizontal right works
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return right, down, forward


def _face_colors(face_colors: np.ndarray | None, n_faces: int) -> np.ndarray:
    if face_colors is None:
        return np.tile(np.asarray(DEFAULT_COLOR, np.float64), (n_faces, 1))
    fc = np.asarray(face_colors)
    if fc.ndim == 1:  # one colour for every face
        fc = np.tile(fc, (n_faces, 1))
    if fc.shape[0] != n_faces:
        raise ValueError(f"face_colors has {fc.shape[0]} rows for {n_faces} faces")
    fc = fc[:, :3]
    if fc.dtype.kind in "ui" or fc.max(initial=0) > 1.0:
        return fc.astype(np.float64) / 255.0
    return fc.astype(np.float64)


def rasterize(screen: np.ndarray, faces: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer ``faces`` given vertex ``screen`` coords (x px, y px, depth; smaller = nearer).

    Returns (face_id (H, W) int64 with -1 for background, depth (H, W) float64 with +inf).
    Ties in depth go to the lower face index, so the result is deterministic.
    """
    n_pix = width * height
    zbuf = np.full(n_pix, np.inf)
    fid = np.full(n_pix, -1, np.int64)
    if len(faces) == 0:
        return fid.reshape(height, width), zbuf.reshape(height, width)
    tri = screen[faces]  # (m, 3, 3)
    x, y, z = tri[..., 0], tri[..., 1], tri[..., 2]
    # Pixel centres at i + 0.5 inside the triangle's bounding box.
    x0 = np.clip(np.ceil(x.min(1) - 0.5), 0, width).astype(np.int64)
    x1 = np.clip(np.floor(x.max(1) - 0.5), -1, width - 1).astype(np.int64)
    y0 = np.clip(np.ceil(y.min(1) - 0.5), 0, height).astype(np.int64)
    y1 = np.clip(np.floor(y.max(1) - 0.5), -1, height - 1).astype(np.int64)
    w = np.maximum(x1 - x0 + 1, 0)
    h = np.maximum(y1 - y0 + 1, 0)
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    counts = np.where(np.abs(area) > 1e-12, w * h, 0)
    safe = np.where(counts > 0, area, 1.0)
    # Barycentric weights are affine in the pixel centre: b = A * cx + B * cy + C per triangle.
    coef = []
    for i, j in ((1, 2), (2, 0)):
        coef.append(
            ((y[:, i] - y[:, j]) / safe, (x[:, j] - x[:, i]) / safe, (x[:, i] * y[:, j] - x[:, j] * y[:, i]) / safe)
        )
    live = np.nonzero(counts)[0]
    if len(live) == 0:
        return fid.reshape(height, width), zbuf.reshape(height, width)
    cum = np.cumsum(counts[live])
    start = 0
    while start < len(live):
        # Take triangles until the chunk holds ~_CHUNK candidates (at least one triangle).
        base = cum[start - 1] if start else 0
        stop = max(int(np.searchsorted(cum, base + _CHUNK, side="right")), start + 1)
        sel = live[start:stop]
        start = stop
        c = counts[sel]
        t = np.repeat(np.arange(len(sel)), c)
        local = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        ws = w[sel][t]
        px = x0[sel][t] + local % ws
        py = y0[sel][t] + local // ws
        cx, cy = px + 0.5, py + 0.5
        st = sel[t]
        (a0, c0, d0), (a1, c1, d1) = coef
        b0 = a0[st] * cx + c0[st] * cy + d0[st]
        b1 = a1[st] * cx + c1[st] * cy + d1[st]
        b2 = 1.0 - b0 - b1
        inside = (b0 >= -1e-9) & (b1 >= -1e-9) & (b2 >= -1e-9)
        if not inside.any():
            continue
        sti = st[inside]
        depth = b0[inside] * z[sti, 0] + b1[inside] * z[sti, 1] + b2[inside] * z[sti, 2]
        pix = (py * width + px)[inside]
        face = sti
        order = np.lexsort((face, depth, pix))
        pix, depth, face = pix[order], depth[order], face[order]
        first = np.ones(len(pix), bool)
        first[1:] = pix[1:] != pix[:-1]
        pix, depth, face = pix[first], depth[first], face[first]
        better = depth < zbuf[pix]
        zbuf[pix[better]] = depth[better]
        fid[pix[better]] = face[better]
    return fid.reshape(height, width), zbuf.reshape(height, width)


def render_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    size: int = 256,
    azimuth_deg: float = 30,
    elevation_deg: float = 20,
    face_colors: np.ndarray | None = None,
    *,
    supersample: int = 2,
    outline: bool = True,
) -> np.ndarray:
    """Shaded RGB thumbnail (size, size, 3) uint8 of a triangle mesh on a white background.

    ``face_colors``: optional (m, 3) per-face colours (uint8 0-255 or float 0-1) or one colour.
    Shading is two-sided Lambert (flipped faces still look lit); ``outline`` darkens depth
    discontinuities so separate parts read clearly; ``supersample`` renders at k x size and
    box-filters down for smooth edges.
    """
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    k = max(int(supersample), 1)
    big = size * k
    colors = _face_colors(face_colors, len(f))
    if len(v) == 0 or len(f) == 0:
        return np.full((size, size, 3), BACKGROUND, np.uint8)

    right, down, forward = view_basis(azimuth_deg, elevation_deg)
    used = v[np.unique(f)]
    sx, sy = used @ right, used @ down
    cx, cy = (sx.min() + sx.max()) / 2, (sy.min() + sy.max()) / 2
    extent = max(sx.max() - sx.min(), sy.max() - sy.min(), 1e-12)
    scale = big * (1 - 2 * _MARGIN) / extent
    screen = np.stack(
        [(v @ right - cx) * scale + big / 2, (v @ down - cy) * scale + big / 2, v @ forward * scale], axis=1
    )
    fid, depth = rasterize(screen, f, big, big)

    # Per-face two-sided Lambert: key light from upper-left-front of the camera plus ambient.
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
    light = -forward * 0.8 - right * 0.35 - down * 0.5
    light /= np.linalg.norm(light)
    shade = 0.35 + 0.65 * np.abs(n @ light)
    face_rgb = colors * shade[:, None]

    img = np.ones((big, big, 3))
    hit = fid >= 0
    img[hit] = face_rgb[fid[hit]]
    if outline:
        img[_edges(depth, hit, scale, k)] *= 0.25
    img = img.reshape(size, k, size, k, 3).mean(axis=(1, 3))
    return np.clip(np.rint(img * 255), 0, 255).astype(np.uint8)


def _edges(depth: np.ndarray, hit: np.ndarray, scale: float, k: int) -> np.ndarray:
    """Pixels on silhouettes or depth jumps (creases between overlapping parts)."""
    d = np.where(hit, depth, np.inf)
    # A jump larger than a few pixels' worth of depth separates surfaces.
    thresh = 3.0 * k
    edge = np.zeros_like(hit)
    for axis in (0, 1):
        a = np.swapaxes(d, 0, axis)
        e = np.swapaxes(edge, 0, axis)
        with np.errstate(invalid="ignore"):  # inf - inf between two background pixels
            jump = np.abs(a[1:] - a[:-1])
        jump = np.where(np.isinf(a[1:]) & np.isinf(a[:-1]), 0.0, jump)
        mark = jump > thresh
        # Mark the nearer side so the line sits on the object, not the background.
        near_lo = a[:-1] <= a[1:]
        e[:-1] |= mark & near_lo
        e[1:] |= mark & ~near_lo
    # Thicken to about one output pixel.
    if k > 1:
        thick = edge.copy()
        for s in range(1, k):
            thick[s:] |= edge[:-s]
            thick[:, s:] |= edge[:, :-s]
        edge = thick
    return edge & hit
