"""How closely the CAD files match the predicted surface, on curved predictions (templates with
their points moved by seeded noise, as a trained network bends them), measured with
OpenCASCADE's own readers and against references that use neither OpenCASCADE nor a mesh:

- the exact bounding box of the bicubic nets (dense sampling: 257 x 257 points per patch, whose
  chordal shortfall is far below the tolerances) and their exact enclosed volume (divergence
  theorem, V = 1/3 Σ ∫∫ S · (S_s x S_t) ds dt: a polynomial of degree ≤ 8 per direction,
  integrated exactly by 5-point Gauss-Legendre);
- ``mesh.obj`` as ``predict`` writes it (40 segments per unit of arc length): a tessellation,
  inside the exact surface by its chordal error; the docs quote the figures asserted here;
- the IGES file of loose faces, sewn by OpenCASCADE as a CAD user would, closes without free
  edges whenever the STEP is a valid solid.

    .venv/bin/python -m pytest tests/test_cad_tolerances.py -s            # fast set, figures printed
    .venv/bin/python -m pytest tests/test_cad_tolerances.py -s -m slow    # 8 categories x 4 sizes x 3 seeds
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from OCP.Bnd import Bnd_Box
from OCP.BRep import BRep_Tool
from OCP.BRepBndLib import BRepBndLib
from OCP.BRepBuilderAPI import BRepBuilderAPI_Sewing
from OCP.BRepCheck import BRepCheck_Analyzer
from OCP.BRepGProp import BRepGProp
from OCP.BRepTools import BRepTools
from OCP.GProp import GProp_GProps
from OCP.TopAbs import TopAbs_FACE, TopAbs_SOLID
from OCP.TopExp import TopExp_Explorer
from OCP.TopoDS import TopoDS

from train.export.bicubic import bernstein3, coons_to_bezier
from train.export.cad_view import read_cad
from train.export.iges import write_iges
from train.export.quadmesh import quad_mesh
from train.export.step import write_step
from train.export.units import CadUnits
from train.templates import FreePoint, load_template

# the figures docs/train.md quotes ("Opening the results in a CAD program")
STEP_BOX = 1e-5  # STEP exact box vs the nets' exact box, of the model's size
STEP_VOLUME = 1e-6  # STEP volume (OpenCASCADE GProp) vs the exact volume, relative (patches.npy is float32: 3e-9)
# mesh.obj box vs the STEP's, of the size: the chordal error at 40 per unit (8.4e-3 on a mug at
# sigma 0.05 whose sharp tip the mesh cuts, 1e-4 at 80 per unit; median 1e-4)
OBJ_BOX = 1e-2
OBJ_VOLUME = 2e-2  # mesh.obj volume vs the STEP's, relative (1.8e-2 on a gun at sigma 0.05; median 4e-4)
IGES_SEW = (1e-4, 1e-6)  # mm: the docs' sewing tolerance and FreeCAD's sewShape() default
MESH_ALPHA = 40.0  # predict's tri_alpha


def curved(category: str, sigma: float, seed: int) -> np.ndarray:
    """Template points moved by seeded noise of ``sigma`` (unit-sphere frame), active patches."""
    tpl = load_template(category)
    p0 = tpl.initial_params().double()
    params = p0 + torch.from_numpy(np.random.default_rng(seed).normal(0.0, sigma, p0.shape))
    return tpl.patches_from_params(params[None])[0].numpy()[tpl.active_patches(None)]


def bent_junction_mug() -> np.ndarray:
    """The mug with one junction point slid to t = 0.98 of its curve and the rest jittered:
    patch 16's side then doubles back on itself, and the single-span IGES of this prediction
    kept two identical free edges at every sewing tolerance (its STEP is a valid solid)."""
    tpl = load_template("mug")
    p0 = tpl.initial_params().double()
    offsets = np.cumsum([0] + [3 if isinstance(p, FreePoint) else 1 for p in tpl.points])
    junctions = [int(offsets[i]) for i, p in enumerate(tpl.points) if not isinstance(p, FreePoint)]
    assert 19 in junctions  # parameter 19 is a junction point's logit
    params = p0 + torch.from_numpy(np.random.default_rng(1).normal(0.0, 0.01, p0.shape)) * (torch.arange(len(p0)) != 19)
    params[19] = 4.0  # sigmoid: t = 0.982
    return tpl.patches_from_params(params[None])[0].numpy()[tpl.active_patches(None)]


def net_box(nets: np.ndarray, samples: int = 257) -> np.ndarray:
    """(2, 3) box of the bicubic nets from a dense grid of surface points."""
    b = bernstein3(np.linspace(0.0, 1.0, samples))
    pts = np.einsum("ui,vj,pijk->puvk", b, b, nets)
    return np.stack([pts.min(axis=(0, 1, 2)), pts.max(axis=(0, 1, 2))])


def _bernstein3_derivative(t: np.ndarray) -> np.ndarray:
    u = 1.0 - t
    return np.stack([-3 * u * u, 3 * u * u - 6 * t * u, 6 * t * u - 3 * t * t, 3 * t * t], axis=-1)


def net_volume(nets: np.ndarray) -> float:
    """Exact volume enclosed by closed, consistently oriented bicubic nets (P, 4, 4, 3)."""
    x, w = np.polynomial.legendre.leggauss(5)
    x, w = 0.5 * (x + 1.0), 0.5 * w  # on [0, 1]
    b, db = bernstein3(x), _bernstein3_derivative(x)
    s = np.einsum("ui,vj,pijk->puvk", b, b, nets)
    ds = np.einsum("ui,vj,pijk->puvk", db, b, nets)
    dt = np.einsum("ui,vj,pijk->puvk", b, db, nets)
    integrand = np.einsum("puvk,puvk->puv", s, np.cross(ds, dt))
    return abs(float(np.einsum("u,v,puv->", w, w, integrand))) / 3.0


def optimal_box(shape) -> np.ndarray:
    """OpenCASCADE's "optimal" box of the exact surfaces (useTriangulation=False, no tolerances).
    It can fall short inside a single-span B-spline face (the form the STEP reader returns): by
    1.2e-3 of the size on a bent guitar, whose face 12 dips below its corners and edges."""
    box = Bnd_Box()
    BRepBndLib.AddOptimal_s(shape, box, False, False)
    return np.array([box.CornerMin().Coord(), box.CornerMax().Coord()])


def sampled_box(shape, samples: int = 65) -> np.ndarray:
    """Box of the shape's faces evaluated by OpenCASCADE on a ``samples``² grid of each face's
    parameter range: what the file's surfaces are, with no optimizer to miss an interior dip."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    ex = TopExp_Explorer(shape, TopAbs_FACE)
    while ex.More():
        face = TopoDS.Face(ex.Current())
        surface = BRep_Tool.Surface_s(face)
        u0, u1, v0, v1 = BRepTools.UVBounds_s(face)
        pts = np.array(
            [surface.Value(u, v).Coord() for u in np.linspace(u0, u1, samples) for v in np.linspace(v0, v1, samples)]
        )
        lo, hi = np.minimum(lo, pts.min(0)), np.maximum(hi, pts.max(0))
        ex.Next()
    return np.stack([lo, hi])


def cad_box(shape) -> np.ndarray:
    """The STEP's box: OpenCASCADE's optimal box widened to the sampled one where it falls short."""
    a, b = optimal_box(shape), sampled_box(shape)
    return np.stack([np.minimum(a[0], b[0]), np.maximum(a[1], b[1])])


def cad_volume(shape) -> float:
    """Enclosed volume. Its sign is the reader's orientation of the solid: OpenCASCADE's STEP
    reader re-orients a solid by point classification, which a shell that passes through itself
    (an unclean prediction) can fool into reading it inside out, so the size is compared."""
    props = GProp_GProps()
    BRepGProp.VolumeProperties_s(shape, props)
    return abs(props.Mass())


def iges_free_edges(path: Path, tol_mm: float) -> int:
    """Free edges left when OpenCASCADE sews the IGES file's faces at ``tol_mm``."""
    sewing = BRepBuilderAPI_Sewing(tol_mm)
    ex = TopExp_Explorer(read_cad(path), TopAbs_FACE)
    while ex.More():
        sewing.Add(ex.Current())
        ex.Next()
    sewing.Perform()
    return sewing.NbFreeEdges()


def measure(patches: np.ndarray, folder: Path, name: str) -> dict:
    """Deviations of the STEP and of mesh.obj from each other and from the exact references."""
    mm = CadUnits().mm
    nets = coons_to_bezier(patches)
    write_step(folder / f"{name}.stp", nets)
    write_iges(folder / f"{name}.igs", nets)
    step = read_cad(folder / f"{name}.stp")
    solid = TopExp_Explorer(step, TopAbs_SOLID).More() and BRepCheck_Analyzer(step).IsValid()
    box, vol = cad_box(step), cad_volume(step)
    exact_box, exact_vol = net_box(nets) * mm, net_volume(nets) * mm**3
    size = float(np.ptp(exact_box, axis=0).max())
    fine = quad_mesh(patches, alpha=MESH_ALPHA)
    obj = trimesh.Trimesh(fine.vertices * mm, fine.triangles(), process=False)
    return {
        "name": name,
        "solid": bool(solid),
        "step_box": float(np.abs(box - exact_box).max()) / size,
        "step_volume": abs(vol - exact_vol) / exact_vol,
        "obj_box": float(np.abs(obj.bounds - box).max()) / size,
        "obj_volume": abs(obj.volume - vol) / vol,
        "iges_free": [iges_free_edges(folder / f"{name}.igs", t) for t in IGES_SEW],
    }


def check(rows: list[dict]) -> None:
    for r in rows:
        print({k: (f"{v:.2e}" if isinstance(v, float) else v) for k, v in r.items()})
    worst = {k: max(r[k] for r in rows) for k in ("step_box", "step_volume", "obj_box", "obj_volume")}
    print("worst", {k: f"{v:.2e}" for k, v in worst.items()})
    assert all(r["solid"] for r in rows), "the premise: each STEP is a valid closed solid"
    assert worst["step_box"] <= STEP_BOX and worst["step_volume"] <= STEP_VOLUME
    assert worst["obj_box"] <= OBJ_BOX and worst["obj_volume"] <= OBJ_VOLUME
    assert all(r["iges_free"] == [0] * len(IGES_SEW) for r in rows), [r for r in rows if any(r["iges_free"])]


def test_cad_files_match_curved_predictions(tmp_path: Path) -> None:
    """Knife predictions including the worst measured (box 6.6e-4 and volume 2.9e-3 for the
    mesh at 40 per unit) and the mug whose single-span IGES did not sew."""
    cases = [("knife", 0.01, 11), ("knife", 0.03, 13), ("knife", 0.03, 23)]
    rows = [measure(curved(c, s, k), tmp_path, f"{c}{k}") for c, s, k in cases]
    rows.append(measure(bent_junction_mug(), tmp_path, "bent_mug"))
    rows.append(measure(curved("guitar", 0.02, 2), tmp_path, "guitar2"))  # optimal box 1.2e-3 short
    rows.append(measure(curved("airplane", 0.05, 25), tmp_path, "airplane25"))  # 2-span IGES did not sew
    check(rows)
    assert max(r["obj_box"] for r in rows) > 10 * STEP_BOX  # the mesh, not the STEP, is the coarse one


def test_step_solid_of_a_self_crossing_prediction_is_not_inside_out() -> None:
    """OpenCASCADE's orientation by classification turned this crossing guitar inside out;
    ``sew_patches`` keeps the orientation whose signed volume is positive."""
    from train.export.step import sew_patches, signed_volume

    nets = coons_to_bezier(curved("guitar", 0.05, 5))
    sewn = sew_patches(nets)
    assert sewn.solid and np.isclose(signed_volume(sewn.shape), net_volume(nets), rtol=1e-9)


def test_exact_references_are_exact() -> None:
    """The references themselves: a unit cube's box and volume from its six bilinear faces."""
    from test_export_quadmesh import AXES, face_patch

    cube = np.stack([face_patch(ax, sg, np.array([0.5, 0.5, 0.5])) for ax, sg in AXES])
    nets = coons_to_bezier(cube)
    assert np.allclose(net_box(nets), [[-0.5] * 3, [0.5] * 3]) and np.isclose(net_volume(nets), 1.0)
    bent = curved("knife", 0.02, 1)
    fine = quad_mesh(bent, alpha=160.0)
    dense = trimesh.Trimesh(fine.vertices, fine.triangles(), process=False)
    assert abs(dense.volume - net_volume(coons_to_bezier(bent))) < 2e-4 * dense.volume  # a fine mesh converges to it


@pytest.mark.slow  # 96 predictions of eight categories, ~2 min
def test_cad_files_match_96_curved_predictions(tmp_path: Path) -> None:
    rows = [
        measure(curved(c, sigma, 10 * seed + int(100 * sigma)), tmp_path, f"{c}{seed}{int(100 * sigma)}")
        for c in ("knife", "bottle", "car", "mug", "gun", "guitar", "airplane", "bathtub")
        for sigma in (0.01, 0.02, 0.03, 0.05)
        for seed in range(3)
    ]
    check([r for r in rows if r["solid"]])
    assert sum(r["solid"] for r in rows) >= 90
