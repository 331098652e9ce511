"""The clean verdict is OpenCASCADE's: the kernel check of the sewn patches agrees with the same
check run on the STEP file read back from disk, over predictions that are clean, folded and
crossing (templates with their points moved by seeded noise of growing size), and it catches
shallow crossings that the triangle-mesh test misses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from train.export.bicubic import coons_to_bezier
from train.export.kernel_check import kernel_verdict, step_file_verdict
from train.export.quadmesh import patch_intersections
from train.export.step import bezier_face, sew_patches, write_step
from train.export.units import CadUnits
from train.templates import load_template

SIGMAS = (0.0, 0.01, 0.02, 0.03, 0.05, 0.08)


def _patches(category: str, sigma: float, seed: int) -> np.ndarray:
    tpl = load_template(category)
    p0 = tpl.initial_params().double()
    params = p0 + torch.from_numpy(np.random.default_rng(seed).normal(0.0, sigma, p0.shape))
    return tpl.patches_from_params(params[None])[0].numpy()[tpl.active_patches(None)]


def _agreement(categories: tuple[str, ...], tmp_path: Path) -> list[tuple]:
    rows, units = [], CadUnits()
    for category in categories:
        for seed, sigma in enumerate(SIGMAS):
            nets = coons_to_bezier(_patches(category, sigma, seed))
            verdict = kernel_verdict(nets * units.mm)  # what predict reports
            path = tmp_path / f"{category}{seed}.stp"
            write_step(path, nets, units)
            faults, solid = step_file_verdict(str(path))  # what a CAD program finds in the file
            rows.append((category, sigma, verdict.clean, faults == 0, solid))
    return rows


def _check(rows: list[tuple]) -> None:
    disagree = [r for r in rows if r[2] != r[3]]
    assert not disagree, f"verdict differs from the kernel on the STEP file: {disagree}"
    assert all(r[4] for r in rows), "every exported prediction here is a closed, valid solid"
    assert {r[2] for r in rows} == {True, False}, "the set holds clean and crossing predictions"


def test_verdict_agrees_with_the_kernel_on_the_step_file(tmp_path: Path) -> None:
    _check(_agreement(("knife",), tmp_path))


@pytest.mark.slow  # 36 predictions of six categories, ~3 min
def test_verdict_agrees_with_the_kernel_on_36_predictions(tmp_path: Path) -> None:
    rows = _agreement(("knife", "bottle", "car", "mug", "gun", "guitar"), tmp_path)
    assert len(rows) >= 30
    _check(rows)


def test_kernel_finds_a_shallow_crossing_the_mesh_test_misses() -> None:
    patches = _patches("knife", 0.02, 2)
    assert patch_intersections(patches, 40.0).clean  # 40 segments per unit: too coarse to see it
    verdict = kernel_verdict(coons_to_bezier(patches) * CadUnits().mm)
    assert not verdict.clean and verdict.patch_pairs
    finer = patch_intersections(patches, 160.0)  # a finer mesh finds crossings among the same patches
    assert set(finer.patch_pairs) & set(verdict.patch_pairs)


def test_template_is_clean_for_the_kernel() -> None:
    verdict = kernel_verdict(coons_to_bezier(_patches("knife", 0.0, 0)))
    assert verdict.clean and verdict.solid and verdict.patch_pairs == []


def _centres(faces: list) -> np.ndarray:
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    out = []
    for face in faces:
        props = GProp_GProps()
        BRepGProp.SurfaceProperties_s(face, props)
        c = props.CentreOfMass()
        out.append((c.X(), c.Y(), c.Z()))
    return np.array(out)


def test_each_patch_keeps_its_own_sewn_face() -> None:
    """Sewing lists its faces in an order of its own (the airplane's is shuffled): the faces the
    verdict maps back to patches must be each patch's own."""
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer

    nets = coons_to_bezier(_patches("airplane", 0.0, 0))
    sewn = sew_patches(nets)
    own = _centres([bezier_face(net) for net in nets])
    assert np.abs(_centres(sewn.patch_faces) - own).max() < 1e-9
    listed, ex = [], TopExp_Explorer(sewn.shape, TopAbs_FACE)
    while ex.More():
        listed.append(ex.Current())
        ex.Next()
    assert len(listed) == len(nets) and not np.allclose(_centres(listed), own)  # why the map is needed


def test_the_patches_the_verdict_names_touch_each_other() -> None:
    """Every pair the kernel names interferes, so its two patches meet: sampled on a fine grid,
    they come within a grid step of each other (patches far apart mean a wrong face map)."""
    from scipy.spatial import cKDTree

    from train.geometry.triangulate import triangulate_patches

    patches = _patches("airplane", 0.01, 3)
    verdict = kernel_verdict(coons_to_bezier(patches) * CadUnits().mm)
    assert verdict.patch_pairs, "the noisy airplane crosses somewhere"
    points = triangulate_patches(torch.from_numpy(patches), 24)[0].numpy()
    for i, j in verdict.patch_pairs:
        gap = cKDTree(points[i]).query(points[j])[0].min()
        assert gap < 0.01, f"patches {i} and {j} are {gap:.3f} apart, yet named as interfering"


def test_a_face_the_kernel_names_alone_is_folded() -> None:
    """A fault with one face is a patch that passes through itself: listed as folded (the
    testbed colours it), not dropped."""
    from OCP.TopAbs import TopAbs_FACE

    from train.export.kernel_check import self_interference, solid_verdict

    sewn = sew_patches(coons_to_bezier(_patches("knife", 0.05, 4)) * CadUnits().mm)
    _, faulty = self_interference(sewn.shape)
    alone = {
        i
        for shapes in faulty
        if len(shapes) == 1 and shapes[0].ShapeType() == TopAbs_FACE
        for i, face in enumerate(sewn.patch_faces)
        if face.IsSame(shapes[0])
    }
    assert alone, "this noisy knife has patches that pass through themselves"
    assert alone <= set(solid_verdict(sewn).folded_patches)
