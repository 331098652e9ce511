"""CAD exports read back by OpenCASCADE's own readers (STEPControl_Reader, IGESControl_Reader),
not by the project's code: faces, shared edges, closed solid, volume and bounding box against
the exact surface of the predicted patches and against the OBJ that ``predict`` writes next to
them, in every unit (the figures: ``test_cad_tolerances``)."""

import sys
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import trimesh
from OCP.BRep import BRep_Tool
from OCP.BRepAdaptor import BRepAdaptor_Surface
from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeSolid, BRepBuilderAPI_Sewing
from OCP.BRepCheck import BRepCheck_Analyzer
from OCP.BRepGProp import BRepGProp
from OCP.GeomAbs import GeomAbs_BSplineSurface
from OCP.GProp import GProp_GProps
from OCP.OCP.collections import IndexedDataMap_TopoDS_Shape_List_TopoDS_Shape_TopTools_ShapeMapHasher as EdgeFaces
from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE, TopAbs_SHELL, TopAbs_SOLID
from OCP.TopExp import TopExp, TopExp_Explorer
from OCP.TopoDS import TopoDS

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import box_sketch, camera  # noqa: E402
from test_cad_tolerances import OBJ_BOX, OBJ_VOLUME, STEP_BOX, STEP_VOLUME, cad_box, net_box, net_volume  # noqa: E402

from train.export.bicubic import coons_to_bezier
from train.export.cad_view import read_cad, render_cad
from train.export.iges import bspline_control, read_iges
from train.export.units import CadUnits
from train.fit import FitSettings, save_checkpoint
from train.model import SketchToPatches
from train.predict import predict
from train.templates import load_template

TEMPLATE = "mug"  # 44 patches with T-junctions: sewing must split edges to share them


# ---- independent reading: OpenCASCADE's readers (via cad_view.read_cad), OpenCASCADE's checks ----


def subshapes(shape, kind) -> list:
    out, exp = [], TopExp_Explorer(shape, kind)
    while exp.More():
        out.append(exp.Current())
        exp.Next()
    return out


def faces_per_edge(shape) -> Counter:
    """How many faces each distinct edge bounds: a sewn closed surface has only 2s."""
    m = EdgeFaces()
    TopExp.MapShapesAndAncestors_s(shape, TopAbs_EDGE, TopAbs_FACE, m)
    return Counter(m.FindFromIndex(i).Extent() for i in range(1, m.Extent() + 1))


def volume(shape) -> float:
    props = GProp_GProps()
    BRepGProp.VolumeProperties_s(shape, props)
    return props.Mass()


def exact_bbox(shape) -> np.ndarray:
    """Tight box of the exact surfaces (not the tessellation, not inflated by tolerances)."""
    return cad_box(shape)


def exact_reference(out: Path, mm: float) -> tuple[np.ndarray, float, float]:
    """(box, volume, size) of the predicted patches' exact surface, in mm."""
    nets = coons_to_bezier(np.load(out / "patches.npy").astype(np.float64))
    box = net_box(nets) * mm
    return box, net_volume(nets) * mm**3, float(np.ptp(box, axis=0).max())


def sew(shape):
    """OpenCASCADE's own sewing of a bag of faces (what a CAD user would do with the IGES)."""
    sewing = BRepBuilderAPI_Sewing(1e-4)
    for f in subshapes(shape, TopAbs_FACE):
        sewing.Add(f)
    sewing.Perform()
    return sewing.SewedShape()


# ---- a real prediction ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def prediction(tmp_path_factory):
    """``predict`` on the mug template with an untrained network whose output layer is perturbed
    (bias = template parameters, small random weights), so the cuboid template comes out curved
    as a trained one would; default units (mm, ×100)."""
    d = tmp_path_factory.mktemp("cad")
    torch.manual_seed(0)
    model = SketchToPatches(load_template(TEMPLATE).initial_params()).eval()
    with torch.no_grad():
        model.out.weight.normal_(0, 0.02)
    s = FitSettings(dataset="-", category="mug", template=TEMPLATE, out=str(d), image_size=32)
    save_checkpoint(d / "checkpoint.pt", model, torch.optim.Adam(model.parameters()), 0, s, load_template(TEMPLATE))
    cv2.imwrite(str(d / "s.png"), box_sketch(np.array([0.5, 0.6, 0.6]), camera(30, 20, 32), 32, 1))
    out = d / "out"
    res = predict(d / "checkpoint.pt", [d / "s.png"], out)
    obj = trimesh.load(out / "mesh.obj", process=True)
    return res, out, obj


def test_step_is_one_sewn_closed_solid_matching_the_obj(prediction):
    res, out, obj = prediction
    mm = CadUnits().mm
    assert mm == 100.0 and res["cad_units"]["units"] == "mm"
    shape = read_cad(out / "patches.stp")
    n_patches = res["patches"]
    assert n_patches == 32  # the mug template at the paper's size (44 before patch budgets)
    assert len(subshapes(shape, TopAbs_SOLID)) == 1 and len(subshapes(shape, TopAbs_SHELL)) == 1
    assert len(subshapes(shape, TopAbs_FACE)) == n_patches
    sharing = faces_per_edge(shape)
    assert set(sharing) == {2} and sharing[2] > 2 * n_patches  # junction edges split and shared
    assert BRep_Tool.IsClosed_s(subshapes(shape, TopAbs_SHELL)[0])
    assert BRepCheck_Analyzer(shape).IsValid()
    assert obj.is_watertight
    want_box, want_volume, size = exact_reference(out, mm)
    box, vol = exact_bbox(shape), volume(shape)
    assert abs(vol - want_volume) <= STEP_VOLUME * want_volume and np.abs(box - want_box).max() <= STEP_BOX * size
    # mesh.obj is a tessellation: inside the exact surface by its chordal error
    assert abs(vol - obj.volume * mm**3) <= OBJ_VOLUME * vol
    assert np.abs(box - obj.bounds * mm).max() <= OBJ_BOX * size
    assert res["step"] == "solid" and res["clean"] and res["problems"] == []
    t = load_template(TEMPLATE)
    template = t.patches_from_params(t.initial_params(torch.float64)[None])[0].numpy()
    assert (
        np.abs(np.load(out / "patches.npy") - template).max() > 0.01
    )  # bent, not the cuboids (0.017 with the 32-patch mug)


def test_iges_keeps_exact_bicubic_surfaces_that_sew_into_the_same_solid(prediction):
    res, out, _ = prediction
    mm = CadUnits().mm
    shape = read_cad(out / "patches.igs")
    faces = subshapes(shape, TopAbs_FACE)
    assert len(faces) == res["patches"]
    for f in faces:
        surf = BRepAdaptor_Surface(TopoDS.Face(f))
        assert surf.GetType() == GeomAbs_BSplineSurface and (surf.UDegree(), surf.VDegree()) == (3, 3)
    assert set(faces_per_edge(shape)) == {1}  # IGES 128: surfaces only, the edges are not shared
    want_box, want_volume, size = exact_reference(out, mm)
    assert np.abs(exact_bbox(shape) - want_box).max() <= STEP_BOX * size
    sewn = sew(shape)
    assert set(faces_per_edge(sewn)) == {2}
    solid = BRepBuilderAPI_MakeSolid(TopoDS.Shell(sewn)).Solid()
    assert abs(abs(volume(solid)) - want_volume) <= STEP_VOLUME * want_volume


def test_mesh_obj_header_records_the_checks(prediction):
    res, out, _ = prediction
    header = [line[2:] for line in (out / "mesh.obj").read_text().splitlines() if line.startswith("# ")]
    fields = dict(line.split(": ", 1) for line in header if ": " in line)
    assert fields["self_intersecting_faces"] == "0" and fields["intersecting_patch_pairs"] == "0"
    assert fields["watertight"] == "True" and fields["clean"] == "True"
    assert res["mesh"]["self_intersecting_faces"] == 0


@pytest.mark.parametrize(
    ("units", "scale", "unit_entity"),
    [("in", None, "'INCH'"), ("m", None, ".METRE."), ("cm", 2.0, ".CENTI."), ("mm", 1.0, ".MILLI.")],
)
def test_units_and_scale_reach_both_cad_files(prediction, tmp_path, units, scale, unit_entity):
    from train.export.bicubic import coons_to_bezier
    from train.export.iges import write_iges
    from train.export.step import write_step

    _, out, _ = prediction
    cad = CadUnits(units, scale)
    nets = coons_to_bezier(np.load(out / "patches.npy").astype(np.float64))
    write_step(tmp_path / "p.stp", nets, cad)
    write_iges(tmp_path / "p.igs", nets, cad)
    want = net_box(nets) * cad.mm  # what a reader working in mm must see
    for name in ("p.stp", "p.igs"):
        box = exact_bbox(read_cad(tmp_path / name))
        assert np.abs(box - want).max() <= STEP_BOX * np.ptp(want, axis=0).max(), name
    unit_lines = [
        line
        for line in (tmp_path / "p.stp").read_text().splitlines()
        if "LENGTH_UNIT" in line or "CONVERSION_BASED_UNIT" in line
    ]
    assert any(unit_entity in line for line in unit_lines)
    # IGES numbers are in the declared unit: the project's reader sees model coords × factor
    raw = np.stack([s["control"] for s in read_iges(tmp_path / "p.igs")])
    assert np.allclose(raw, np.stack([bspline_control(n) for n in nets]) * cad.factor)
    if scale is None:  # the default size is the same 100 mm per model unit in every unit
        assert np.isclose(cad.mm, 100.0)


def test_step_is_byte_identical_across_runs(prediction, tmp_path):
    from train.export.bicubic import coons_to_bezier
    from train.export.step import write_step

    _, out, _ = prediction
    nets = coons_to_bezier(np.load(out / "patches.npy").astype(np.float64))
    for run in ("a", "b"):  # OpenCASCADE numbers products per process: the 2nd write must not differ
        (tmp_path / run).mkdir()
        write_step(tmp_path / run / "patches.stp", nets)
    assert (tmp_path / "a" / "patches.stp").read_bytes() == (tmp_path / "b" / "patches.stp").read_bytes()


def test_bad_units_are_refused():
    with pytest.raises(ValueError, match="unknown units 'ft'"):
        CadUnits("ft")
    with pytest.raises(ValueError, match="scale must be positive"):
        CadUnits("mm", 0.0)


def test_cad_view_renders_the_step_faces(prediction):
    _, out, _ = prediction
    img = render_cad(out / "patches.stp", size=96)
    assert img.shape == (96, 96, 3)
    colours = {tuple(c) for c in img.reshape(-1, 3)[::7]}
    assert len(colours) > 20  # shaded faces of several colours, not a blank or a single fill


def test_open_surface_is_written_as_one_sewn_shell(tmp_path):
    from train.export.bicubic import coons_to_bezier
    from train.export.step import write_step

    t = load_template("sphere24")
    patches = t.patches_from_params(t.initial_params(torch.float64)[None])[0].numpy()[1:]  # a hole
    sewn = write_step(tmp_path / "open.stp", coons_to_bezier(patches))
    assert not sewn.solid and sewn.free_edges == 4
    shape = read_cad(tmp_path / "open.stp")
    assert len(subshapes(shape, TopAbs_SOLID)) == 0 and len(subshapes(shape, TopAbs_SHELL)) == 1
    assert len(subshapes(shape, TopAbs_FACE)) == 23
    assert faces_per_edge(shape) == Counter({2: 44, 1: 4})  # sewn everywhere but the hole's rim
