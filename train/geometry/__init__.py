"""Batched torch geometry of cubic Bézier curves and Coons patches.

A batch of patches is a tensor ``(..., P, 4, 4, 3)``: four cubic boundary curves per patch with
four control points each, in the paper's orientation (c1 bottom s 0→1, c2 right t 0→1, c3 top
from P(1,1) to P(0,1), c4 left from P(0,1) to P(0,0)). Parameters ``st`` are ``(S, 2)`` shared by
all patches or ``(P, S, 2)`` per patch.
"""

from train.geometry.bezier import bezier_derivative, bezier_eval, bezier_subdivide, blossom
from train.geometry.construct import line_curve, patch_from_corners
from train.geometry.coons import (
    PatchSamples,
    coons_jacobian,
    coons_normals,
    coons_partials,
    coons_points,
    evaluate_patches,
)
from train.geometry.grid import grid_params, grid_triangulation
from train.geometry.sampling import sample_surface_uniform, samples_per_patch, uniform_params
from train.geometry.triangulate import triangulate_patches, welded_mesh

__all__ = [
    "PatchSamples",
    "bezier_derivative",
    "bezier_eval",
    "bezier_subdivide",
    "blossom",
    "coons_jacobian",
    "coons_normals",
    "coons_partials",
    "coons_points",
    "evaluate_patches",
    "grid_params",
    "grid_triangulation",
    "line_curve",
    "patch_from_corners",
    "samples_per_patch",
    "sample_surface_uniform",
    "triangulate_patches",
    "uniform_params",
    "welded_mesh",
]
