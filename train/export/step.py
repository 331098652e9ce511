"""STEP (AP214) export of patches as one sewn B-rep, through OpenCASCADE (the OCP binding).

Each patch becomes a face on its exact bicubic Bézier surface (``coons_to_bezier``; OpenCASCADE
writes it as a single-span B-spline surface). ``BRepBuilderAPI_Sewing`` then merges the
coincident boundary edges, splitting a long edge where shorter ones meet it (template
T-junctions), so neighbouring faces share one edge. A sewn shell without free edges becomes a
solid (oriented outward) and is written as a MANIFOLD_SOLID_BREP; anything else is written as
the sewn shell(s), so a CAD program opens one connected surface either way.

Coordinates are given to OpenCASCADE in millimetres (its working unit) and the writer converts
them to the declared ``units``. The header's timestamp, names and product are fixed, so the same
patches give a byte-identical file.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from pipeline.core.atomic import atomic_path
from train.export.units import CadUnits

# relative to the model's extent: far above rounding of shared control points, far below any
# feature of a prediction
SEW_TOLERANCE = 1e-6
_HEADER_TIME = "2021-01-01T00:00:00"


@dataclasses.dataclass
class SewnPatches:
    shape: object  # TopoDS_Shape: a solid, a shell or a compound of shells
    faces: int
    free_edges: int
    solid: bool
    # the sewn face of each patch, in patch order (sewing lists its faces in an order of its own)
    patch_faces: list


def quiet_opencascade() -> None:
    """OpenCASCADE prints transfer statistics to stdout; keep only failures."""
    from OCP.Message import Message, Message_Gravity

    for printer in Message.DefaultMessenger_s().Printers():
        printer.SetTraceLevel(Message_Gravity.Message_Fail)


def bezier_face(net: np.ndarray):
    """A face on the bicubic Bézier surface of ``net (4, 4, 3)`` (natural bounds [0, 1]²)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace
    from OCP.Geom import Geom_BezierSurface
    from OCP.gp import gp_Pnt
    from OCP.OCP.collections import Array2_gp_Pnt

    poles = Array2_gp_Pnt(1, 4, 1, 4)
    for i in range(4):
        for j in range(4):
            poles.SetValue(i + 1, j + 1, gp_Pnt(*(float(c) for c in net[i, j])))
    maker = BRepBuilderAPI_MakeFace(Geom_BezierSurface(poles), 1e-7)
    if not maker.IsDone():
        raise ValueError(f"OpenCASCADE could not make a face of the patch (error {maker.Error()})")
    return maker.Face()


def sew_patches(nets: np.ndarray) -> SewnPatches:
    """Faces of ``nets (P, 4, 4, 3)`` sewn into shared-edge shells; a closed one made a solid."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeSolid, BRepBuilderAPI_Sewing
    from OCP.BRepLib import BRepLib
    from OCP.TopAbs import TopAbs_SHELL
    from OCP.TopoDS import TopoDS

    nets = np.asarray(nets, dtype=np.float64)
    extent = float(np.ptp(nets.reshape(-1, 3), axis=0).max()) if nets.size else 1.0
    sewing = BRepBuilderAPI_Sewing(SEW_TOLERANCE * max(extent, 1e-12))
    made = [bezier_face(net) for net in nets]
    for face in made:
        sewing.Add(face)
    sewing.Perform()
    shape = sewing.SewedShape()
    patch_faces = [sewing.Modified(face) if sewing.IsModified(face) else face for face in made]
    free = sewing.NbFreeEdges()
    solid = False
    if free == 0 and shape.ShapeType() == TopAbs_SHELL:
        made = BRepBuilderAPI_MakeSolid(TopoDS.Shell(shape))
        if made.IsDone():
            oriented = made.Solid()
            BRepLib.OrientClosedSolid_s(oriented)  # outward normals, positive volume
            if signed_volume(oriented) < 0:
                # its point classification is fooled by a shell that passes through itself (an
                # unclean prediction) and can leave the solid inside out; the signed volume (the
                # divergence theorem over the faces as oriented) is not: take the shell's
                # orientation that encloses a positive volume
                shells = (TopoDS.Shell(shape), TopoDS.Shell(shape.Reversed()))
                oriented = max((BRepBuilderAPI_MakeSolid(sh).Solid() for sh in shells), key=signed_volume)
            shape, solid = oriented, True
    return SewnPatches(shape, len(nets), int(free), solid, patch_faces)


def signed_volume(shape) -> float:
    """Volume enclosed by ``shape``'s faces as oriented (negative when they face inward)."""
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    props = GProp_GProps()
    BRepGProp.VolumeProperties_s(shape, props)
    return props.Mass()


def write_step(path: str | Path, nets: np.ndarray, units: CadUnits = CadUnits()) -> SewnPatches:
    """Write model-frame bicubic nets ``(P, 4, 4, 3)`` as a sewn AP214 STEP file (atomically)."""
    from OCP.APIHeaderSection import APIHeaderSection_MakeHeader
    from OCP.IFSelect import IFSelect_ReturnStatus
    from OCP.Interface import Interface_Static
    from OCP.StepBasic import StepBasic_Product
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Controller, STEPControl_Writer
    from OCP.TCollection import TCollection_HAsciiString

    quiet_opencascade()
    sewn = sew_patches(np.asarray(nets, dtype=np.float64) * units.mm)
    STEPControl_Controller.Init_s()
    # the writer reads these process-wide settings when it converts; set them for every file
    for key, value in (("write.step.schema", "AP214IS"), ("write.step.unit", units.step)):
        if not Interface_Static.SetCVal_s(key, value):
            raise RuntimeError(f"OpenCASCADE rejected STEP setting {key}={value}")
    writer = STEPControl_Writer()
    if writer.Transfer(sewn.shape, STEPControl_AsIs) != IFSelect_ReturnStatus.IFSelect_RetDone:
        raise RuntimeError(f"{path}: OpenCASCADE could not convert the patches to STEP")
    text = TCollection_HAsciiString
    model = writer.Model()
    for k in range(1, model.NbEntities() + 1):
        entity = model.Value(k)
        if isinstance(entity, StepBasic_Product):  # OpenCASCADE numbers products per process
            entity.SetId(text(Path(path).stem))
            entity.SetName(text(Path(path).stem))
    header = APIHeaderSection_MakeHeader(model)
    header.SetName(text(Path(path).name))
    header.SetTimeStamp(text(_HEADER_TIME))
    header.SetAuthorValue(1, text("sketch2patch"))
    header.SetOrganizationValue(1, text("sketch2patch"))
    header.SetOriginatingSystem(text("sketch2patch (OpenCASCADE)"))
    header.SetDescriptionValue(1, text("Coons patches as bicubic B-spline faces, sewn"))
    with atomic_path(path) as tmp:
        if writer.Write(str(tmp)) != IFSelect_ReturnStatus.IFSelect_RetDone:
            raise OSError(f"cannot write STEP file {path}")
    return sewn
