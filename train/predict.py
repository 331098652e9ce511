"""Prediction from sketches and export of the result.

Writes to the output folder: ``patches.json`` (template format with the predicted geometry),
``patches.npy`` (P, 4, 4, 3), ``mesh.obj`` (welded watertight triangles; its ``#`` header
records the mesh checks), ``quads.obj`` (quad mesh from the subdivision integer program),
``patches.stp`` (sewn B-rep solid, STEP AP214), ``patches.igs`` (exact bicubic NURBS, IGES 5.3)
and ``render.png`` (self-intersecting faces in red). Meshes and ``patches.*`` stay in the model
frame; the CAD files are scaled and unit-tagged by ``CadUnits``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import torch

from pipeline.core.atomic import write_json, write_npy
from pipeline.core.images import save_png
from pipeline.core.settings_io import setting
from pipeline.core.thumbnails import DEFAULT_COLOR, render_mesh
from train.augmentation import STEADY_COPIES, SteadyAverage
from train.data import to_network
from train.errors import UsageError, one_line
from train.export.bicubic import coons_to_bezier
from train.export.iges import write_iges
from train.export.kernel_check import KernelVerdict, solid_verdict
from train.export.obj import edge_report, write_obj
from train.export.quadmesh import quad_mesh
from train.export.step import write_step
from train.export.units import CadFileSettings, CadUnits
from train.fit import TrainedRun, load_run
from train.geometry.intersections import Intersections, mesh_intersections
from train.mirror_average import MirrorAverage, mirror_averaged
from train.sketch_input import Framing, SketchError, normalize_sketch
from train.templates import FreePoint, JunctionPoint, Template, save_template

# The optional parts of the shipped category templates, for --help (a test keeps it in step with
# train/templates/data/; a checkpoint's own template may have others: --list-parts).
SHIPPED_PARTS = "airplane engine; bathtub faucet; car spoiler; gun magazine, scope, stock; knife guard, pommel"


@dataclasses.dataclass(frozen=True)
class PredictSettings(CadFileSettings):
    """``python -m train predict``: one flag per field."""

    checkpoint: str = setting(help="checkpoint.pt or best.pt of a run")
    sketch: tuple[str, ...] = setting(
        help="one or more drawings (views) of the same object: PNG, JPEG, WebP, TIFF (required unless --list-parts)"
    )
    out: str = setting(help="output folder (required unless --list-parts)")
    part: tuple[str, ...] = setting(
        (),
        "optional parts of the checkpoint's template on or off, NAME=on|off; --list-parts prints a "
        f"checkpoint's parts (shipped templates: {SHIPPED_PARTS}); a wrong name is an error listing them",
    )
    mirror_average: bool = setting(
        False,
        "answer with the mean of the network's reading of the drawings and of their left-right flips, "
        "mirrored back (symmetric templates; twice the inference cost)",
    )
    list_parts: bool = setting(False, "print the optional parts of the checkpoint's template and exit")
    json: bool = setting(False, "print the result as JSON on stdout (it is always written to OUT/prediction.json)")

    def parts(self) -> dict[str, bool]:
        """``--part NAME=on|off`` as {name: present}."""
        out = {}
        for item in self.part:
            name, _, state = item.partition("=")
            if state not in ("on", "off"):
                raise UsageError(f"--part {item}: use NAME=on or NAME=off")
            out[name] = state == "on"
        return out


def template_parts(template: Template) -> dict[str, dict[str, int]]:
    """The template's optional parts: {name: {"patches": n, "closing_patches": m}}; a part's
    patches go when it is off, its closing patches (if any) come in to seal the surface."""
    return {
        name: {
            "patches": len(template.optional_parts.get(name, [])),
            "closing_patches": len(template.closing_patches.get(name, [])),
        }
        for name in template.part_names
    }


def describe_parts(template: Template) -> str:
    """``template_parts`` in words, one part a line (``--list-parts``)."""
    parts = template_parts(template)
    if not parts:
        return f"template {template.name}: no optional parts (--part does not apply)"
    lines = [f"template {template.name}: optional parts (--part NAME=on|off)"]
    for name, n in parts.items():
        closing = f", {n['closing_patches']} closing patches when off" if n["closing_patches"] else ""
        lines.append(f"  {name}: {n['patches']} patches{closing}")
    return "\n".join(lines)


def check_parts(template: Template, parts: dict[str, bool]) -> list[int]:
    """The patch ids for ``parts`` (``Template.active_patches``), or a UsageError naming the
    unknown part(s) and the template's own."""
    unknown = sorted(set(parts) - set(template.part_names))
    if unknown:
        has = ", ".join(template.part_names) or "none"
        raise UsageError(
            f"--part {', '.join(unknown)}: the checkpoint's template ({template.name}) has no such optional part; "
            f"its optional parts: {has}"
        )
    return template.active_patches(parts)


@dataclasses.dataclass(frozen=True)
class Sketches:
    """A person's drawings as the network sees them: ``tensor`` (1, V, 1, S, S), the images
    (uint8, black on white) and what normalization did to each (``train.sketch_input``)."""

    tensor: torch.Tensor
    images: list[np.ndarray]
    reports: list[dict]


def load_sketches(paths: list[str | Path], size: int, framing: Framing = Framing()) -> Sketches:
    """Image files (any of PNG, JPEG, WebP, TIFF; any paper, polarity, framing) -> network input,
    each normalized like the training sketches (``normalize_sketch``)."""
    images, reports = [], []
    for p in paths:
        if not Path(p).is_file():
            raise UsageError(f"{p}: no such sketch file" + (" (it is a folder)" if Path(p).is_dir() else ""))
        try:
            norm = normalize_sketch(Path(p).read_bytes(), size, framing, name=str(p))
        except SketchError as exc:
            raise UsageError(str(exc)) from None
        except (OSError, cv2.error) as exc:
            raise UsageError(f"{p}: not a readable image ({one_line(exc)})") from None
        images.append(norm.image)
        reports.append({"sketch": str(p), **norm.report})
    tensor = torch.from_numpy(np.stack([to_network(i) for i in images]))[None]
    return Sketches(tensor, images, reports)


def save_inputs(out: Path, sketches: Sketches) -> None:
    """``input.png``: what the network saw, the views side by side."""
    save_png(out / "input.png", np.concatenate(sketches.images, axis=1))


def predicted_template(template: Template, params: torch.Tensor) -> Template:
    """The template with its points moved to the prediction (junction t from the logits)."""
    pos = template.points_from_params(params[None].double())[0].numpy()
    offsets = np.cumsum([0] + [3 if isinstance(p, FreePoint) else 1 for p in template.points])
    points = []
    for i, p in enumerate(template.points):
        if isinstance(p, FreePoint):
            points.append(FreePoint(tuple(float(x) for x in pos[i])))
        else:
            points.append(JunctionPoint(p.curve, float(torch.sigmoid(params[offsets[i]].double()))))
    return dataclasses.replace(
        template, points=points, name=f"{template.name}-prediction", metadata={**template.metadata, "predicted": True}
    )


def mesh_problems(edges: dict, kernel: KernelVerdict, free_edges: int) -> list[str]:
    """What keeps an exported prediction from being clean, in words (empty list: clean). The
    self-intersection verdict is the CAD kernel's (OpenCASCADE's check of the sewn solid, as a
    CAD program runs it), not the triangle mesh's, which misses shallow crossings."""
    problems = []
    if not edges["watertight"]:
        problems.append(
            f"mesh not watertight ({edges['boundary_edges']} boundary, {edges['nonmanifold_edges']} non-manifold edges)"
        )
    if not kernel.solid:
        problems.append(f"STEP is an open shell, not a solid ({free_edges} free edges)")
    if not kernel.clean:
        pairs = ", ".join(f"{a}-{b}" for a, b in kernel.patch_pairs) or "-"
        folded = f"; folded patches {', '.join(map(str, kernel.folded_patches))}" if kernel.folded_patches else ""
        problems.append(f"the CAD kernel finds {kernel.faulty} self-interferences (patch pairs {pairs}{folded})")
    return problems


def _obj_header(
    edges: dict, hits: Intersections, kernel: KernelVerdict, units: CadUnits, problems: list[str]
) -> list[str]:
    pairs = " ".join(f"{a}-{b}" for a, b in kernel.patch_pairs)
    return [
        "sketch2patch prediction mesh; model frame (unit-sphere normalized)",
        f"cad_files: patches.stp patches.igs in {units.units}, scale {units.factor:g} per model unit",
        *(f"{k}: {v}" for k, v in {**edges, **hits.summary()}.items()),
        f"cad_kernel_interferences: {kernel.faulty}",
        f"intersecting_patch_list: {pairs or '-'}",
        f"clean: {not problems}",
    ]


def export_patches(
    patches: np.ndarray,
    out: str | Path,
    units: CadUnits = CadUnits(),
    quad_alpha: float = 12.0,
    tri_alpha: float = 40.0,
) -> dict:
    """All file exports of one patch set; returns a summary (counts, mesh checks, CAD units)."""
    out = Path(out)
    write_npy(out / "patches.npy", patches.astype(np.float32))
    nets = coons_to_bezier(patches)
    write_iges(out / "patches.igs", nets, units)
    sewn = write_step(out / "patches.stp", nets, units)
    qm = quad_mesh(patches, alpha=quad_alpha)
    write_obj(out / "quads.obj", qm.vertices, qm.faces, qm.patch_of_face)
    fine = quad_mesh(patches, alpha=tri_alpha)
    tris = fine.triangles()
    edges = edge_report(tris)
    patch_of_tri = np.repeat(fine.patch_of_face, 2)
    hits = mesh_intersections(fine.vertices, tris, patch_of_tri)
    kernel = solid_verdict(sewn)
    problems = mesh_problems(edges, kernel, sewn.free_edges)
    write_obj(out / "mesh.obj", fine.vertices, tris, comments=_obj_header(edges, hits, kernel, units, problems))
    colors = np.tile(np.asarray(DEFAULT_COLOR, np.float64), (len(tris), 1))
    crossing = sorted({i for pair in kernel.patch_pairs for i in pair} | set(kernel.folded_patches))
    colors[np.isin(patch_of_tri, crossing)] = (0.95, 0.6, 0.55)  # patches the kernel names
    colors[hits.faces] = (0.9, 0.1, 0.1)  # where the mesh sees them cross
    save_png(out / "render.png", render_mesh(fine.vertices, tris, size=384, face_colors=colors))
    return {
        "patches": int(len(patches)),
        "quads": int(len(qm.faces)),
        "triangles": int(len(tris)),
        "mesh": {**edges, **hits.summary()},
        "cad_kernel": {
            "self_interferences": kernel.faulty,
            "patch_pairs": [list(p) for p in kernel.patch_pairs],
            "folded_patches": kernel.folded_patches,
        },
        "intersecting_patch_pairs": [list(p) for p in kernel.patch_pairs],
        "step": "solid" if sewn.solid else f"open shell, {sewn.free_edges} free edges",
        "cad_units": units.describe(),
        "curve_counts": qm.counts.tolist(),
        "clean": not problems,
        "problems": problems,
    }


@torch.no_grad()
def predict(
    checkpoint: str | Path,
    sketches: list[str | Path],
    out: str | Path,
    parts: dict[str, bool] | None = None,
    units: CadUnits = CadUnits(),
    mirror_average: bool = False,
) -> dict:
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: not a folder (--out)")
    run = load_run(checkpoint)
    return predict_run(mirror_averaged(run) if mirror_average else run, sketches, out, parts, units)


def verdict_line(clean: bool, problems: list[str]) -> str:
    """The verdict in words, as ``predict`` prints it last (a mesh can be watertight and still
    pass through itself)."""
    return "prediction is clean" if clean else "NOT CLEAN: " + "; ".join(problems)


@torch.no_grad()
def predict_params(run: TrainedRun, images: torch.Tensor) -> torch.Tensor:
    """The network's parameters for normalized sketches ``(B, V, 1, S, S)``: its output averaged
    over small jitters of the sketch (``train.augmentation.SteadyAverage``), so that resampling a
    person's drawing (a rescan, a redraw at another size) moves the prediction little."""
    return SteadyAverage(run.model)(images)


@torch.no_grad()
def predict_run(
    run: TrainedRun,
    sketches: list[str | Path],
    out: str | Path,
    parts: dict[str, bool] | None = None,
    units: CadUnits = CadUnits(),
) -> dict:
    """:func:`predict` with a run already loaded (the browser testbed keeps its checkpoints loaded)."""
    out = Path(out)
    template = run.template
    # checked before anything is written, so a wrong --part or sketch leaves no files behind;
    # a part switched off drops its patches and brings in its closing patches: still closed
    keep = check_parts(template, parts or {})
    seen = load_sketches(sketches, run.settings.image_size, run.framing)
    params = predict_params(run, seen.tensor)[0]
    save_template(predicted_template(template, params), out / "patches.json")
    save_inputs(out, seen)
    patches = template.patches_from_params(params[None].double())[0].numpy()[keep]
    result = {
        "input": seen.reports,
        "jitter_copies": STEADY_COPIES,
        "mirror_average": isinstance(run.model, MirrorAverage),
        **export_patches(patches, out, units),
    }
    write_json(out / "prediction.json", result)
    return result
