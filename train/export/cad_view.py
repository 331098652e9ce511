"""Picture of a STEP or IGES file as a CAD kernel sees it: OpenCASCADE reads and tessellates the
B-rep, one colour per face, drawn with the project's mesh renderer.

    python -m train.export.cad_view DIR/patches.stp --out preview.png [--size 512] [--azimuth 35 -60 ...]

What the picture shows is the file's geometry after a real import (units converted, faces
trimmed), so it is a check of the export, not of the patches it was made from.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from pipeline.core.errors import ModelError
from pipeline.core.images import save_png
from pipeline.core.settings_io import add_arguments, from_args, setting
from pipeline.core.thumbnails import render_mesh

# colour-blind-safe palette cycled over faces (Okabe–Ito, lightened for shading)
_PALETTE = (
    np.array(
        [
            [230, 159, 0],
            [86, 180, 233],
            [0, 158, 115],
            [240, 228, 66],
            [0, 114, 178],
            [213, 94, 0],
            [204, 121, 167],
            [170, 170, 170],
        ]
    )
    / 255.0
)


def read_cad(path: str | Path):
    """The shape in a ``.stp``/``.step``/``.igs``/``.iges`` file, in millimetres."""
    from OCP.IFSelect import IFSelect_ReturnStatus
    from OCP.IGESControl import IGESControl_Reader
    from OCP.STEPControl import STEPControl_Reader

    from train.export.step import quiet_opencascade

    quiet_opencascade()
    path = Path(path)
    reader = STEPControl_Reader() if path.suffix.lower() in (".stp", ".step") else IGESControl_Reader()
    if not path.is_file() or reader.ReadFile(str(path)) != IFSelect_ReturnStatus.IFSelect_RetDone:
        raise ModelError(path, "not a readable STEP/IGES file")
    if reader.TransferRoots() == 0:
        raise ModelError(path, "no shape could be transferred from the file")
    return reader.OneShape()


def tessellate(shape, rel_deflection: float = 1e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCASCADE's triangulation: vertices (V, 3), triangles (T, 3), face index per triangle."""
    from OCP.Bnd import Bnd_Box
    from OCP.BRep import BRep_Tool
    from OCP.BRepBndLib import BRepBndLib
    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.TopAbs import TopAbs_FACE, TopAbs_REVERSED
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopLoc import TopLoc_Location
    from OCP.TopoDS import TopoDS

    box = Bnd_Box()
    BRepBndLib.Add_s(shape, box)
    size = float(np.ptp(np.array([box.CornerMin().Coord(), box.CornerMax().Coord()]), axis=0).max())
    BRepMesh_IncrementalMesh(shape, rel_deflection * size, False, 0.3, False)
    verts, tris, owner = [], [], []
    offset, k = 0, 0
    exp = TopExp_Explorer(shape, TopAbs_FACE)
    while exp.More():
        face = TopoDS.Face(exp.Current())
        loc = TopLoc_Location()
        mesh = BRep_Tool.Triangulation_s(face, loc)
        if mesh is not None:
            trsf = loc.Transformation()
            pts = [mesh.Node(i).Transformed(trsf).Coord() for i in range(1, mesh.NbNodes() + 1)]
            t = np.array([mesh.Triangle(i).Get() for i in range(1, mesh.NbTriangles() + 1)]) - 1
            if face.Orientation() == TopAbs_REVERSED:
                t = t[:, ::-1]
            verts.append(np.array(pts))
            tris.append(t + offset)
            owner.append(np.full(len(t), k))
            offset += len(pts)
        k += 1
        exp.Next()
    if not verts:
        raise ValueError("the shape has no faces to tessellate")
    return np.concatenate(verts), np.concatenate(tris), np.concatenate(owner)


def render_cad(
    path: str | Path, size: int = 512, azimuths: tuple[float, ...] = (35.0,), elevation_deg: float = 25
) -> np.ndarray:
    """RGB image of a CAD file's faces (one colour each) as imported by OpenCASCADE, one
    ``size`` square per azimuth, side by side."""
    v, t, owner = tessellate(read_cad(path))
    colors = _PALETTE[owner % len(_PALETTE)]
    views = [
        render_mesh(v, t, size=size, azimuth_deg=az, elevation_deg=elevation_deg, face_colors=colors) for az in azimuths
    ]
    return np.concatenate(views, axis=1)


@dataclasses.dataclass(frozen=True)
class CadViewSettings:
    file: str = setting(help="a .stp/.step or .igs/.iges file", positional=True)
    out: str = setting(help="PNG to write")
    size: int = setting(512, "pixels per view")
    azimuth: tuple[float, ...] = setting((35.0,), "one view per azimuth (degrees)")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m train.export.cad_view", description=__doc__.split("\n\n")[0])
    add_arguments(p, CadViewSettings)
    a = from_args(CadViewSettings, p.parse_args(argv))
    save_png(a.out, render_cad(a.file, a.size, a.azimuth))
    print(f"saved {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
