"""Data model of a procedural shape: labelled parts, their cuboids, and the OBJ + sidecar writer."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

import numpy as np

from pipeline.core.atomic import write_bytes, write_json
from pipeline.core.schema import sidecar_path


@dataclasses.dataclass
class Part:
    """One separately-meshed part (closed and outward-oriented unless a defect says otherwise)."""

    label: str
    vertices: np.ndarray  # (n, 3) float64
    faces: np.ndarray  # (m, 3) int64


@dataclasses.dataclass
class Cuboid:
    """Axis-aligned bounding box of one part; seeds template construction later."""

    label: str
    lo: np.ndarray  # (3,)
    hi: np.ndarray  # (3,)


@dataclasses.dataclass
class ProceduralModel:
    category: str
    index: int
    model_id: str
    seed: int
    parts: list[Part]
    cuboids: list[Cuboid]
    defects: list[str]
    detached: bool = False  # some parts deliberately clear of the others (separate bodies)

    @property
    def n_faces(self) -> int:
        return int(sum(len(p.faces) for p in self.parts))

    def merged(self) -> tuple[np.ndarray, np.ndarray]:
        """All parts concatenated (not unioned) as one (vertices, faces) pair."""
        verts, faces, off = [], [], 0
        for p in self.parts:
            verts.append(p.vertices)
            faces.append(p.faces + off)
            off += len(p.vertices)
        return np.concatenate(verts), np.concatenate(faces)

    def sidecar(self) -> dict:
        return {
            "category": self.category,
            "index": self.index,
            "model_id": self.model_id,
            "seed": self.seed,
            "parts": [{"label": p.label, "n_faces": int(len(p.faces))} for p in self.parts],
            "cuboids": [{"label": c.label, "lo": _round(c.lo), "hi": _round(c.hi)} for c in self.cuboids],
            "defects": list(self.defects),
            "detached": bool(self.detached),
        }

    def obj_text(self) -> str:
        """Wavefront OBJ: one ``o`` group per part, fixed float formatting (deterministic bytes)."""
        out = io.StringIO()
        out.write(f"# procedural {self.category} {self.model_id} seed {self.seed}\n")
        off = 1
        for p in self.parts:
            out.write(f"o {p.label}\n")
            np.savetxt(out, p.vertices, fmt="v %.6f %.6f %.6f")
            np.savetxt(out, p.faces + off, fmt="f %d %d %d")
            off += len(p.vertices)
        return out.getvalue()

    def write(self, obj_path: Path) -> None:
        """Write the OBJ and its sidecar (``schema.sidecar_path``), each atomically."""
        obj_path = Path(obj_path)
        write_bytes(obj_path, self.obj_text().encode())
        write_json(sidecar_path(obj_path), self.sidecar())


def _round(a: np.ndarray) -> list[float]:
    return [round(float(x), 6) for x in a]


def cuboid_of(part: Part) -> Cuboid:
    used = part.vertices[np.unique(part.faces)] if len(part.faces) else part.vertices
    return Cuboid(part.label, used.min(axis=0), used.max(axis=0))


def make_part(label: str, mesh: tuple[np.ndarray, np.ndarray]) -> Part:
    v, f = mesh
    return Part(label, np.ascontiguousarray(v, np.float64), np.ascontiguousarray(f, np.int64))


def mirrored_pair(label: str, mesh: tuple[np.ndarray, np.ndarray]) -> list[Part]:
    """``mesh`` built on the +x side and its mirror across x = 0, labelled ``<label>_r`` / ``_l``."""
    v, f = mesh
    return [make_part(f"{label}_r", mesh), make_part(f"{label}_l", (v * np.array([-1.0, 1.0, 1.0]), f[:, ::-1]))]
