"""The CAD kernel's verdict on a sewn patch solid: OpenCASCADE's self-interference check.

``BOPAlgo_ArgumentAnalyzer`` with its self-interference mode is what CAD tools run before a
Boolean (FreeCAD's "Check geometry" with BOP check included): it intersects every pair of
sub-shapes of the solid exactly (faces on their bicubic surfaces, not a triangulation) and
reports the pairs that interfere. Shared edges of sewn neighbours do not count; a shallow
crossing that a coarse triangulation misses does.

Sewing lists its faces in an order of its own; ``sew_patches`` keeps each patch's sewn face, and
the faulty faces map back to patch indices through them.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class KernelVerdict:
    patch_pairs: list[tuple[int, int]]  # distinct faces (patches) that interfere, a < b
    folded_patches: list[int]  # faces that interfere with themselves or their own edges
    faulty: int  # interferences the kernel reported
    solid: bool  # the patches sewed into a closed solid

    @property
    def clean(self) -> bool:
        return self.faulty == 0


def _face_index(faces: list, shape) -> int | None:
    for i, f in enumerate(faces):
        if f.IsSame(shape):
            return i
    return None


def self_interference(shape, fuzzy: float = 0.0) -> tuple[int, list[list]]:
    """(number of interferences, the faulty sub-shapes of each) of a TopoDS shape."""
    from OCP.BOPAlgo import BOPAlgo_ArgumentAnalyzer

    analyzer = BOPAlgo_ArgumentAnalyzer()
    analyzer.SetShape1(shape)
    analyzer.SelfInterMode = True
    if fuzzy > 0:
        analyzer.SetFuzzyValue(fuzzy)
    analyzer.Perform()
    results = list(analyzer.GetCheckResult())
    return len(results), [list(r.GetFaultyShapes1()) for r in results]


def kernel_verdict(nets: np.ndarray) -> KernelVerdict:
    """Sew bicubic nets ``(P, 4, 4, 3)`` (as the STEP export does) and run the kernel's check."""
    from train.export.step import quiet_opencascade, sew_patches

    quiet_opencascade()
    return solid_verdict(sew_patches(np.asarray(nets, dtype=np.float64)))


def solid_verdict(sewn) -> KernelVerdict:
    """The kernel's check of patches already sewn (``train.export.step.SewnPatches``, what
    ``write_step`` returns), faults mapped to patch indices."""
    from OCP.TopAbs import TopAbs_FACE

    faces = sewn.patch_faces
    count, faulty = self_interference(sewn.shape)
    pairs, folded = set(), set()
    for shapes in faulty:
        # an edge or vertex stands for the faces it bounds
        owners = [[_face_index(faces, s)] if s.ShapeType() == TopAbs_FACE else _owner_faces(faces, s) for s in shapes]
        if len(owners) == 1:  # a face that passes through itself
            folded.update(a for a in owners[0] if a is not None)
            continue
        for a in owners[0]:
            for b in owners[1]:
                if a is None or b is None:
                    continue
                if a == b:
                    folded.add(a)
                else:
                    pairs.add((min(a, b), max(a, b)))
    return KernelVerdict(sorted(pairs), sorted(folded), count, sewn.solid)


def _owner_faces(faces: list, sub) -> list[int]:
    """Faces that contain the edge or vertex ``sub``."""
    from OCP.TopExp import TopExp_Explorer

    out = []
    for i, f in enumerate(faces):
        ex = TopExp_Explorer(f, sub.ShapeType())
        while ex.More():
            if ex.Current().IsSame(sub):
                out.append(i)
                break
            ex.Next()
    return out


def step_file_verdict(path: str) -> tuple[int, bool]:
    """(interferences, is a valid solid) of a STEP file read back from disk: what another CAD
    program sees, independent of the code that wrote it."""
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.IFSelect import IFSelect_ReturnStatus
    from OCP.STEPControl import STEPControl_Reader
    from OCP.TopAbs import TopAbs_SOLID
    from OCP.TopExp import TopExp_Explorer

    from train.export.step import quiet_opencascade

    quiet_opencascade()
    reader = STEPControl_Reader()
    if reader.ReadFile(str(path)) != IFSelect_ReturnStatus.IFSelect_RetDone:
        raise ValueError(f"{path}: OpenCASCADE cannot read this STEP file")
    reader.TransferRoots()
    shape = reader.OneShape()
    solid = TopExp_Explorer(shape, TopAbs_SOLID).More() and BRepCheck_Analyzer(shape).IsValid()
    count, _ = self_interference(shape)
    return count, bool(solid)
