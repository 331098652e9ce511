"""The fit stage's work: a category's template fitted to each model's surface (no sketch, no network).

"By fitting a template to a 3D model, our method automatically converts the model to a set of
Coons patches" (the paper, §4, Fig. 7): the same template, hence the same patch layout, on every
model of a category. As in ``bench/bench_fit_ceiling.py``: Adam on the template's parameters of
all models of a batch at once, the training loss without the collision term, each model's absent
optional parts masked and its part groups matched apart exactly as in training
(``Objective.batch_terms``); then the plain L_Ch of the template and of the fit (the quality
table's: nearest points, midpoint grid, no groups).

The loss is the sum over the batch, not the mean, so a model's gradients and hence (Adam is
per element) its fit do not depend on which models share its batch; the (s, t) samples of each
step come from one generator seeded by (seed, "fit", category), the same for every batch.

The dataset side runs this module as its own process (``python -m train.patch_fit JOB``; it never
imports the trainer): the job file (``FIT_JOB_FILE``) names the models and their targets
(``FIT_TARGETS_FILE``), each model's ``FIT_PARAMS_FILE`` and ``record.json`` go to its folder of
the stage, and the answer (CPU seconds) to ``FIT_RESULT_FILE``. One thread, deterministic
algorithms: the same job gives the same bytes.

``export_fit`` (``python -m train export-fit``) writes one model's fit, read from the shards, as
``train.predict`` writes a prediction: STEP, IGES, OBJ, quad mesh (docs/dataset.md).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import sys
import tarfile
import time
from pathlib import Path

import numpy as np
import torch

from pipeline.core.atomic import dumps_json, read_json, write_json, write_npy
from pipeline.core.errors import ModelError
from pipeline.core.fit_settings import PatchFitSettings
from pipeline.core.model_loop import is_fatal
from pipeline.core.records import read_record, write_failed, write_ok
from pipeline.core.schema import (
    FIT_JOB_FILE,
    FIT_MEMBER,
    FIT_MEMBERS,
    FIT_PARAMS_FILE,
    FIT_PARAMS_MEMBER,
    FIT_RESULT_FILE,
    FIT_TARGETS_FILE,
    POINT_PART_NAMES,
    PRESENT_PARTS,
    SPLITS,
    sample_key,
    shard_glob,
)
from pipeline.core.settings_io import from_dict, setting
from train.errors import UsageError
from train.export.units import CadFileSettings
from train.losses.weights import LossWeights
from train.objective import Objective
from train.template_fit import fit_batch
from train.templates import Template, load_template, save_template


@dataclasses.dataclass(frozen=True)
class Target:
    """One model's target: surface points (M, 6) and, where the source has part labels, each
    point's family (index into ``point_part_names``) and the families present."""

    model_id: str
    points: np.ndarray
    point_parts: np.ndarray | None = None
    point_part_names: list[str] | None = None
    present_parts: list[str] | None = None


@dataclasses.dataclass(frozen=True)
class Fitted:
    params: np.ndarray  # float32 (D,)
    active_patches: list[int]
    chamfer_template: float
    chamfer_fitted: float


def template_sha256(template: Template) -> str:
    """sha256 of the template's canonical JSON: what its fits were made from."""
    return hashlib.sha256(dumps_json(template.to_json()).encode()).hexdigest()


def _batch(targets: list[Target]) -> dict:
    """The loader's batch layout (``train.data.collate``), so the objective masks as in training."""
    m = len(targets[0].points)  # the dataset side hands every model the same number of points
    parts = [t.point_parts if t.point_parts is not None else np.full(m, -1, np.int64) for t in targets]
    return {
        "points": torch.from_numpy(np.stack([t.points for t in targets]).astype(np.float32)),
        "point_parts": torch.from_numpy(np.stack(parts).astype(np.int64)),
        "meta": [{PRESENT_PARTS: t.present_parts, POINT_PART_NAMES: t.point_part_names} for t in targets],
    }


def plain_chamfer(objective: Objective, params: torch.Tensor, batch: dict) -> torch.Tensor:
    """(B,) L_Ch as the quality table measures it: nearest points, midpoint grid, no part groups."""
    w = LossWeights(normal=0.0, flat=0.0, collision=0.0, template_normal=0.0, symmetry=0.0)
    return objective.batch_terms(params, batch, objective.sample_st(None), w, training=False)["chamfer"]


def fit_targets(
    template: Template, targets: list[Target], settings: PatchFitSettings, seed: int, category: str
) -> list[Fitted]:
    """The template fitted to every target at once (see the module's docstring)."""
    objective = Objective(template, settings.points, match_normals=template.match_normals)
    batch = _batch(targets)
    start = template.initial_params()[None].expand(len(targets), -1).clone()
    params = fit_batch(objective, batch, settings, seed, category)
    with torch.no_grad():
        before, after = plain_chamfer(objective, start, batch), plain_chamfer(objective, params, batch)
    masks = objective.patch_mask(batch["meta"], torch.device("cpu"))
    out = []
    for i in range(len(targets)):
        active = list(range(template.num_patches)) if masks is None else masks[i].nonzero()[:, 0].tolist()
        out.append(Fitted(params[i].numpy().astype(np.float32), active, float(before[i]), float(after[i])))
    return out


# ---------------------------------------------------------------- the stage's job


def _targets(job: dict, folder: Path) -> tuple[list[Target], list[dict]]:
    """The job's targets (from ``FIT_TARGETS_FILE``) and their job entries."""
    with np.load(folder / FIT_TARGETS_FILE, allow_pickle=False) as arrays:
        targets = []
        for i, m in enumerate(job["models"]):
            parts = arrays[f"parts_{i}"] if f"parts_{i}" in arrays else None
            targets.append(Target(m["model_id"], arrays[f"points_{i}"], parts, m.get("names"), m.get("present")))
    return targets, job["models"]


def _check(fitted: Fitted, entry: dict) -> None:
    if not (np.isfinite(fitted.params).all() and np.isfinite([fitted.chamfer_template, fitted.chamfer_fitted]).all()):
        raise ModelError(entry["path"], "the fit diverged (non-finite parameters or L_Ch)")


def _record_fields(template: Template, sha: str, settings: PatchFitSettings, fitted: Fitted) -> dict:
    """The record's fields: FIT_FIELDS (also the shard's fit member), and where the result is."""
    return {
        "template": template.name,
        "template_sha256": sha,
        "patches": template.num_patches,
        "active_patches": fitted.active_patches,
        "steps": settings.steps,
        "lr": settings.lr,
        "points": settings.points,
        "chamfer_template": round(fitted.chamfer_template, 7),
        "chamfer_fitted": round(fitted.chamfer_fitted, 7),
        "files": {"params": FIT_PARAMS_FILE},
    }


def run_job(job_path: str | Path) -> dict:
    """Fit the job's models that have no record yet, write each one's result and record (a bad
    model is recorded failed with the reason, the others go on), and answer in FIT_RESULT_FILE."""
    job_path = Path(job_path)
    t0 = time.process_time()
    torch.set_num_threads(1)
    torch.use_deterministic_algorithms(True)
    job = read_json(job_path)
    settings = from_dict(PatchFitSettings, job["settings"])
    category, seed, stage_dir = job["category"], int(job["seed"]), Path(job["stage_dir"])
    targets, entries = _targets(job, job_path.parent)
    todo = [i for i, e in enumerate(entries) if read_record(stage_dir / category / e["work_id"]) is None]
    fitted_n = 0
    try:
        # the file as the stage's key saw it, when the stage snapshotted one (a built-in has none)
        template = load_template(job_path.parent / job["template_file"] if "template_file" in job else job["template"])
    except Exception as exc:  # a missing or broken template fails every model of the category, each recorded
        if is_fatal(exc):
            raise
        for i in todo:
            err = ModelError(entries[i]["path"], f"template {job['template']!r}: {type(exc).__name__}: {exc}")
            write_failed(
                stage_dir / category / entries[i]["work_id"], err, category=category, model_id=entries[i]["model_id"]
            )
        todo = []
    if todo:
        sha = template_sha256(template)
        results = _fit_isolating(template, [targets[i] for i in todo], settings, seed, category)
        for i, res in zip(todo, results):
            folder = stage_dir / category / entries[i]["work_id"]
            ids = {"category": category, "model_id": entries[i]["model_id"]}
            try:
                if isinstance(res, BaseException):
                    raise res
                _check(res, entries[i])
            except ModelError as err:
                write_failed(folder, err, **ids)
                continue
            except Exception as exc:  # noqa: BLE001 - a library error on odd input: this model's failure
                write_failed(folder, ModelError(entries[i]["path"], f"fit: {type(exc).__name__}: {exc}"), **ids)
                continue
            write_npy(folder / FIT_PARAMS_FILE, res.params)
            write_ok(folder, **ids, **_record_fields(template, sha, settings, res))
            fitted_n += 1
    answer = {"fitted": fitted_n, "cpu_seconds": round(time.process_time() - t0, 3)}
    write_json(job_path.parent / FIT_RESULT_FILE, answer)
    return answer


def _fit_isolating(
    template: Template, targets: list[Target], settings: PatchFitSettings, seed: int, category: str
) -> list[Fitted | Exception]:
    """All targets in one batch; if the batch fails, each alone, so a bad model fails only itself
    (the sum loss makes a model's fit the same alone as in its batch)."""
    try:
        return list(fit_targets(template, targets, settings, seed, category))
    except Exception as exc:
        if is_fatal(exc):
            raise  # out of memory, a library missing: the task fails, nothing is recorded
        if len(targets) == 1:
            return [exc]
    return [_fit_alone(template, t, settings, seed, category) for t in targets]


def _fit_alone(template: Template, target: Target, settings: PatchFitSettings, seed: int, category: str):
    try:
        return fit_targets(template, [target], settings, seed, category)[0]
    except Exception as exc:
        if is_fatal(exc):
            raise
        return exc


# ---------------------------------------------------------------- export of a fit


@dataclasses.dataclass(frozen=True)
class ExportFitSettings(CadFileSettings):
    """``python -m train export-fit``: one model's fitted patches as CAD files and meshes."""

    dataset: str = setting(help="dataset folder built with --fit-patches")
    category: str = setting(help="the model's category")
    model: str = setting(help="the model's id (meta.json's model_id, e.g. 00003)")
    out: str = setting(help="output folder")


def read_fit(dataset: str | Path, category: str, model_id: str) -> tuple[np.ndarray, dict, Path]:
    """A model's fit from the shards: (parameters, FIT_MEMBER fields, the shard it is in)."""
    root = Path(dataset) / category
    if not root.is_dir():
        raise UsageError(f"{root}: no such category folder in the dataset")
    key = sample_key(category, model_id)
    for split in SPLITS:
        for shard in sorted(root.glob(shard_glob(split))):
            try:
                with tarfile.open(shard, mode="r:") as tar:
                    found = {
                        i.name[len(key) + 1 :]: i
                        for i in tar.getmembers()
                        if i.isfile() and i.name.startswith(key + ".")
                    }
                    if not found:
                        continue
                    if not set(FIT_MEMBERS) <= set(found):
                        raise UsageError(f"{shard}: {key} has no fit (build the dataset with --fit-patches)")
                    params = np.load(io.BytesIO(tar.extractfile(found[FIT_PARAMS_MEMBER]).read()), allow_pickle=False)
                    info = json.loads(tar.extractfile(found[FIT_MEMBER]).read())
            except (OSError, tarfile.TarError, ValueError) as exc:
                raise UsageError(f"{shard}: unreadable shard ({type(exc).__name__}: {exc})") from None
            return params, info, shard
    raise UsageError(f"{root}: no model {model_id!r} (sample {key}) in its shards")


def export_fit(settings: ExportFitSettings) -> dict:
    """Write the model's fitted patches (the template's active ones) as ``train.predict`` writes a
    prediction: patches.json, patches.npy, patches.stp, patches.igs, mesh.obj, quads.obj,
    render.png, and export.json (the fit's figures and the checks' summary)."""
    from train.predict import export_patches, predicted_template

    out = Path(settings.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: not a folder (--out)")
    units = settings.cad_units()
    params, info, shard = read_fit(settings.dataset, settings.category, settings.model)
    template = load_template(info["template"])
    if template_sha256(template) != info["template_sha256"]:
        raise UsageError(f"{shard}: fitted to another version of template {info['template']!r}; rebuild the fit")
    p = torch.from_numpy(params.astype(np.float32))
    fitted = predicted_template(template, p)
    save_template(
        dataclasses.replace(
            fitted, name=f"{template.name}-fit-{settings.model}", metadata={**template.metadata, "fitted": True}
        ),
        out / "patches.json",
    )
    patches = template.patches_from_params(p[None].double())[0].numpy()[info["active_patches"]]
    result = {
        "category": settings.category,
        "model": settings.model,
        **{k: info[k] for k in ("template", "chamfer_template", "chamfer_fitted")},
        **export_patches(patches, out, units),
    }
    write_json(out / "export.json", result)
    return result


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print(f"usage: python -m train.patch_fit JOB_DIR/{FIT_JOB_FILE}", file=sys.stderr)
        return 2
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    print(json.dumps(run_job(argv[0])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
