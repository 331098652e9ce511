"""``evaluate --images DIR``: a checkpoint on a folder of people's drawings instead of shards.

Each image in DIR (PNG, JPEG, WebP, TIFF; one view per image) is normalized exactly as
``predict`` normalizes it (``train.predict.load_sketches``: ``train.sketch_input.normalize_sketch``
with the checkpoint's framing), and every prediction gets the CAD kernel's verdict
(``train.export.kernel_check``, as ``predict`` and ``evaluate --cad-check`` run it). Where a mesh
``DIR/<stem>.obj|.ply|.stl`` lies beside an image, it is that drawing's ground truth: taken in
the category's orientation, normalized as the prepare stage normalizes models (bounding-box
centre to the origin, farthest vertex at radius 1), sampled area-uniformly (``n_points`` of the
run, seeded) and measured with ``evaluate``'s own metrics (``batch_metrics``), for the network
and for the template alone.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import trimesh

from pipeline.core.atomic import write_json
from pipeline.core.normalize import apply_transform, unit_sphere_transform
from pipeline.core.seeding import rng_for
from train.errors import UsageError, one_line
from train.evaluate import batch_metrics, check_evaluate_args, metric_names
from train.export.bicubic import coons_to_bezier
from train.export.kernel_check import kernel_verdict
from train.export.units import CadUnits
from train.fit import load_run
from train.mirror_average import mirror_averaged
from train.objective import Objective
from train.predict import load_sketches, predict_params

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".webp", ".tif", ".tiff")
MESH_SUFFIXES = (".obj", ".ply", ".stl")


def image_files(folder: str | Path) -> list[Path]:
    """The drawings in ``folder`` (not its subfolders), sorted by name; an error if there are none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise UsageError(f"{folder}: no such folder (--images)")
    found = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not found:
        raise UsageError(f"{folder}: no images in it ({', '.join(IMAGE_SUFFIXES)}) (--images)")
    return found


def ground_truth(image: Path) -> Path | None:
    """The mesh beside ``image`` with its stem, if any (.obj before .ply before .stl)."""
    for suffix in MESH_SUFFIXES:
        for candidate in (image.with_suffix(suffix), image.with_suffix(suffix.upper())):
            if candidate.is_file():
                return candidate
    return None


def target_points(mesh_path: Path, n: int) -> torch.Tensor:
    """``(n, 6)`` xyz + outward normal, area-uniform on the mesh in the unit-sphere frame
    (seeded by the file name, so a rerun measures the same points)."""
    try:
        mesh = trimesh.load(mesh_path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds for a broken file
        raise UsageError(f"{mesh_path}: not a readable mesh ({one_line(exc)})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0 or not mesh.area > 0:
        raise UsageError(f"{mesh_path}: not a readable mesh (no faces with area)")
    try:
        center, scale = unit_sphere_transform(np.asarray(mesh.vertices))
    except ValueError as exc:
        raise UsageError(f"{mesh_path}: {exc}") from None
    mesh = trimesh.Trimesh(apply_transform(mesh.vertices, center, scale), mesh.faces, process=False)
    if mesh.is_volume and mesh.volume < 0:  # normals point outward, as the prepared models' do
        mesh.invert()
    points, faces = trimesh.sample.sample_surface(mesh, n, seed=rng_for(0, "evaluate-images", mesh_path.name))
    normals = mesh.face_normals[faces]
    return torch.from_numpy(np.concatenate([points, normals], 1).astype(np.float32))


@torch.no_grad()
def evaluate_images(
    checkpoint: str | Path,
    folder: str | Path,
    taus: tuple[float, ...] = (0.02, 0.05),
    limit: int | None = None,
    out: str | Path | None = None,
    cad_check: bool = True,
    mirror_average: bool = False,
    points: int | None = None,
) -> dict:
    """Per image: what normalization did, the kernel's verdict and (with a ground-truth mesh)
    the metrics; means over the images for the network (``model``) and the template alone
    (``template``, on images with ground truth); saved as JSON when ``out``. ``mirror_average``:
    the network answers through :class:`train.mirror_average.MirrorAverage`, as predict's flag.
    ``points``: sample points per shape for the metrics (default: the run's)."""
    check_evaluate_args(1, taus, limit, points)
    files = image_files(folder)[:limit]
    run = load_run(checkpoint)
    if mirror_average:
        run = mirror_averaged(run)
    template, s = run.template, run.settings
    n_points = points or s.n_points
    objective = Objective(template, n_points)
    names = metric_names(tuple(taus))
    keep = template.active_patches(None)  # every optional part present, as predict without --part
    base = template.initial_params()[None]
    mm = CadUnits().mm
    rows, sums, measured, verdicts = (
        [],
        {"model": dict.fromkeys(names, 0.0), "template": dict.fromkeys(names, 0.0)},
        0,
        [],
    )
    for path in files:
        seen = load_sketches([path], s.image_size, run.framing)
        params = predict_params(run, seen.tensor)
        row: dict = {"image": path.name, "input": {k: v for k, v in seen.reports[0].items() if k != "sketch"}}
        if cad_check:
            patches = template.patches_from_params(params.double())[0].numpy()[keep]
            v = kernel_verdict(coons_to_bezier(patches) * mm)
            row["cad_kernel"] = {
                "clean": v.clean,
                "solid": v.solid,
                "self_interferences": v.faulty,
                "patch_pairs": [list(p) for p in v.patch_pairs],
                "folded_patches": v.folded_patches,
            }
            verdicts.append(v.clean)
        truth = ground_truth(path)
        if truth is not None:
            batch = {"points": target_points(truth, n_points)[None], "meta": [{}]}
            row["ground_truth"] = truth.name
            for name, p in (("model", params), ("template", base)):
                gen = torch.Generator().manual_seed(0)  # the same samples for the network as for the template
                values = {k: float(t[0]) for k, t in batch_metrics(objective, p, batch, tuple(taus), gen).items()}
                row[name] = values
                for k, value in values.items():
                    sums[name][k] += value
            measured += 1
        rows.append(row)
    result = {
        "checkpoint": str(checkpoint),
        "mirror_average": mirror_average,
        "step": run.step,
        "images": str(folder),
        "samples": len(rows),
        "with_ground_truth": measured,
        "points": n_points,
        "fscore_taus": list(taus),
        "chamfer_note": "chamfer = paper's unsquared Jacobian-weighted L_Ch; chamfer_sq_x1000 = peers' squared x1000",
        "model": {k: v / measured for k, v in sums["model"].items()} if measured else {},
        "template": {k: v / measured for k, v in sums["template"].items()} if measured else {},
        "per_image": rows,
    }
    if verdicts:
        result["model"]["cad_clean"] = sum(verdicts) / len(verdicts)
        result["cad_checked"] = len(verdicts)
    if out:
        write_json(out, result)
    return result


def format_rows(result: dict) -> str:
    """One line per image: its verdict and, with ground truth, the network's Chamfer against it."""
    lines = [f"{'image':<28}{'clean':>8}{'chamfer':>12}{'template':>12}  ground truth"]
    for r in result["per_image"]:
        clean = "-" if "cad_kernel" not in r else ("yes" if r["cad_kernel"]["clean"] else "NO")
        ch = f"{r['model']['chamfer']:>12.5f}" if "model" in r else f"{'-':>12}"
        tp = f"{r['template']['chamfer']:>12.5f}" if "template" in r else f"{'-':>12}"
        lines.append(f"{r['image'][:27]:<28}{clean:>8}{ch}{tp}  {r.get('ground_truth', '-')}")
    return "\n".join(lines)
