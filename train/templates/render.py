"""Render a template to an RGB image: patches triangulated on a grid, each in its own colour."""

from __future__ import annotations

import colorsys

import numpy as np
import torch

from pipeline.core.thumbnails import render_mesh
from train.geometry.triangulate import triangulate_patches
from train.templates.template import Template


def patch_colors(n: int) -> np.ndarray:
    """``n`` distinct RGB colours (golden-ratio hue steps, alternating lightness), uint8 (n, 3)."""
    out = []
    for i in range(n):
        h = (i * 0.618033988749895) % 1.0
        light = (0.55, 0.68, 0.45)[i % 3]
        out.append(colorsys.hls_to_rgb(h, light, 0.65))
    return (np.array(out).reshape(-1, 3) * 255).round().astype(np.uint8)


def template_mesh(
    tpl: Template, k: int = 10, params: torch.Tensor | None = None, parts: dict[str, bool] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid triangulation of the active patches (``parts``: see ``Template.active_patches``):
    vertices (V, 3), faces (F, 3), patch id per face."""
    ids = np.array(tpl.active_patches(parts), dtype=int)
    with torch.no_grad():
        p = tpl.initial_params(torch.float64) if params is None else params.double()
        patches = tpl.patches_from_params(p.reshape(1, -1))[0][ids]
        verts, faces = triangulate_patches(patches, k)  # (P, k*k, 3), (f, 3)
    n_p = verts.shape[0]
    v = verts.reshape(-1, 3).numpy()
    offs = (np.arange(n_p) * k * k)[:, None, None]
    f = (faces.numpy()[None] + offs).reshape(-1, 3)
    owner = np.repeat(ids, len(faces))
    return v, f, owner


def _seam_mask(k: int) -> np.ndarray:
    """Faces of one patch's grid that touch its boundary (drawn darker so seams show)."""
    i_t, i_s = np.meshgrid(np.arange(k - 1), np.arange(k - 1), indexing="ij")
    edge = (i_t == 0) | (i_s == 0) | (i_t == k - 2) | (i_s == k - 2)
    return np.concatenate([edge.reshape(-1), edge.reshape(-1)])


def render_template(
    tpl: Template,
    size: int = 384,
    views: tuple[tuple[float, float], ...] = ((30.0, 20.0), (210.0, 25.0)),
    k: int = 12,
    params: torch.Tensor | None = None,
    parts: dict[str, bool] | None = None,
) -> np.ndarray:
    """Side-by-side views (uint8 RGB, size × len(views)·size) with one colour per patch."""
    v, f, owner = template_mesh(tpl, k, params, parts)
    colors = patch_colors(tpl.num_patches)[owner].astype(np.float64)
    seam = np.tile(_seam_mask(k), len(np.unique(owner)))
    colors[seam] *= 0.8
    images = [
        render_mesh(v, f, size=size, azimuth_deg=az, elevation_deg=el, face_colors=colors.astype(np.uint8))
        for az, el in views
    ]
    return np.concatenate(images, axis=1)
