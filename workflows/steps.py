"""What each Luigi task does, as plain functions (no Luigi here), so they can be called and
tested directly. Each batch step writes a small JSON listing its models' outcomes:

``{"stage", "category", "batch", "models": [{"model_id", "work_id", "status", "stage", "error"?}]}``

Steps take the category's model list (workflows.listing): a batch is a slice of it, and models are
handed to the stages under their work ids, which name their output folders.

A model that failed upstream is carried forward with the stage where it failed, so the shard
step sees every failure of the category with its reason.
"""

from __future__ import annotations

import os
import socket
import stat
import time
from pathlib import Path

from pipeline.core.atomic import read_json, storage_error, write_json
from pipeline.core.hashing import file_sha256
from pipeline.core.records import Progress, model_dir
from pipeline.core.schema import FRAGMENT, RECORD, SAMPLES_FILE
from pipeline.core.stage_keys import settings_hash
from pipeline.dataset.manifest import (
    build_manifest,
    category_fragment,
    content_checksum,
    read_fragment,
    read_manifest,
    write_fragment,
    write_manifest,
)
from pipeline.dataset.shards import ModelDirs, ShardSet, list_shards, retire_category, write_category_shards
from workflows.build_settings import BuildSettings, template_fingerprints, template_snapshot
from workflows.listing import duplicate_outcome, model_ref

BATCHES = "_batches"
RUNS = "_runs"


# ---------------------------------------------------------------- paths


def batch_models(s: BuildSettings, lst: dict, batch: int) -> list[dict]:
    return lst["models"][batch * s.batch_size : (batch + 1) * s.batch_size]


def batch_path(s: BuildSettings, stage: str, lst: dict, batch: int) -> Path:
    """A batch's outcome file, named by the work ids it holds: a batch whose models (or their
    content) changed is a new batch, an unchanged one stays done whatever else was added."""
    return batch_file(s.stage_dir(stage), s, lst, batch)


def batch_file(stage_dir: Path, s: BuildSettings, lst: dict, batch: int) -> Path:
    """``batch_path`` under a stage folder already resolved (where the batch's models went)."""
    return stage_dir / lst["category"] / BATCHES / batch_name(s, lst, batch)


def batch_name(s: BuildSettings, lst: dict, batch: int) -> str:
    """The file name of ``batch_path`` (the same in every stage), without the settings' stage key:
    the console names every batch once and looks the folder up."""
    ids = [m["work_id"] for m in batch_models(s, lst, batch)]
    return f"{batch:05d}-{settings_hash({'ids': ids})}.json"


def n_batches(n_models: int, batch_size: int) -> int:
    return -(-n_models // batch_size)


# ---------------------------------------------------------------- steps


def write_source_list(s: BuildSettings, category: str) -> int:
    """Generate the procedural source's models and store their list (file sources store theirs
    while listing); returns the count."""
    from pipeline.sources.layouts import list_models
    from workflows.listing import current_listing, list_path, procedural_tag

    if not s.is_procedural:
        return len(current_listing(s, category)["models"])
    refs = list_models(s.source, category, s.limit, s.seed, Path(s.work_dir))
    write_json(
        list_path(s, category, procedural_tag(s)),
        {
            "category": category,
            "models": [{"model_id": r.model_id, "path": str(r.path), "source": r.source} for r in refs],
        },
    )
    return len(refs)


def _outcome(m: dict, stage: str, rec: dict | None) -> dict:
    out = {
        "model_id": m["model_id"],
        "work_id": m["work_id"],
        "stage": stage,
        "status": "failed" if rec is None else rec.get("status", "failed"),
    }
    if rec is None:
        out["error"] = {"path": m["path"], "reason": "no record written"}
    elif out["status"] != "ok":
        out["error"] = rec.get("error") or {"path": m["path"], "reason": "unknown failure"}
    return out


def _write_batch(
    s: BuildSettings,
    stage: str,
    lst: dict,
    batch: int,
    outcomes: list[dict],
    t0: float,
    stage_dir: Path | None = None,
    **extra,
) -> dict:
    """The batch's outcome file, in ``stage_dir`` when given: the folder its models were written to."""
    # wall seconds are kept in the work folder only (never in shards or manifest) for stage shares
    doc = {
        "stage": stage,
        "category": lst["category"],
        "batch": batch,
        "models": outcomes,
        "seconds": round(time.perf_counter() - t0, 3),
        **extra,
    }
    write_json(batch_file(stage_dir or s.stage_dir(stage), s, lst, batch), doc)
    return doc


def _upstream(s: BuildSettings, stage: str, lst: dict, batch: int) -> tuple[list[dict], list[dict]]:
    """Models (list entries) that passed ``stage`` in this batch, and the outcomes of those that did not."""
    doc = read_json(batch_path(s, stage, lst, batch))
    passed = {m["work_id"] for m in doc["models"] if m["status"] == "ok"}
    return (
        [m for m in batch_models(s, lst, batch) if m["work_id"] in passed],
        [m for m in doc["models"] if m["status"] != "ok"],
    )


def prepare_step(s: BuildSettings, lst: dict, batch: int, progress: Progress = None) -> dict:
    t0 = time.perf_counter()
    from pipeline.prepare.batch import prepare_batch

    models = batch_models(s, lst, batch)
    copies = {m["work_id"]: duplicate_outcome(m) for m in models if duplicate_outcome(m)}  # failed, never built
    todo = [m for m in models if m["work_id"] not in copies]
    records = iter(
        prepare_batch(
            [model_ref(lst["category"], m) for m in todo],
            s.stage_dir("prepare"),
            s.prepare_settings(),
            progress,
            s.part_label_settings(),
        )
    )
    return _write_batch(
        s,
        "prepare",
        lst,
        batch,
        [copies.get(m["work_id"]) or _outcome(m, "prepare", next(records)) for m in models],
        t0,
    )


def render_step(s: BuildSettings, lst: dict, batch: int, progress: Progress = None, crash_retries: int = 1) -> dict:
    """Render the batch's prepared models in one Blender process. If Blender crashes or hangs,
    the batch is retried ``crash_retries`` times (finished models keep their records, so a retry
    resumes); after that the models still unrendered are recorded failed with the cause."""
    t0 = time.perf_counter()
    from render.batch import RenderBatchError, render_batch

    category = lst["category"]
    ok, failed = _upstream(s, "prepare", lst, batch)
    prep = s.stage_dir("prepare")
    from pipeline.core.schema import LINE_MESH_FILE  # the source's surface: its sharp edges are drawn

    items = [(m["work_id"], model_dir(prep, category, m["work_id"]) / LINE_MESH_FILE) for m in ok]
    records: list[dict] = []
    crashes: list[str] = []
    for attempt in range(crash_retries + 1 if items else 0):
        try:
            records = render_batch(
                category,
                items,
                s.stage_dir("render"),
                s.render_settings(),
                s.seed,
                progress,
                on_crash="record" if attempt == crash_retries else "raise",
            )
            break
        except RenderBatchError as exc:
            crashes.append(str(exc))
            if progress is not None:
                progress(
                    0,
                    len(items),
                    f"render {category} batch {batch}: retry {attempt + 1}/{crash_retries} after: {exc}"[:300],
                )
    outcomes = failed + [_outcome(m, "render", rec) for m, rec in zip(ok, records)]
    return _write_batch(
        s,
        "render",
        lst,
        batch,
        sorted(outcomes, key=lambda m: m["model_id"]),
        t0,
        attempts=len(crashes) + bool(records),
        crashes=crashes,
    )


def augment_step(s: BuildSettings, lst: dict, batch: int, progress: Progress = None) -> dict:
    t0 = time.perf_counter()
    from augment.batch import augment_batch

    category = lst["category"]
    ok, failed = _upstream(s, "render", lst, batch)
    rend = s.stage_dir("render")
    items = [(m["work_id"], model_dir(rend, category, m["work_id"])) for m in ok]
    records = (
        augment_batch(category, items, s.stage_dir("augment"), s.augment_settings(), s.seed, progress) if items else []
    )
    outcomes = failed + [_outcome(m, "augment", rec) for m, rec in zip(ok, records)]
    return _write_batch(s, "augment", lst, batch, sorted(outcomes, key=lambda m: m["model_id"]), t0)


def fit_step(s: BuildSettings, lst: dict, batch: int, progress: Progress = None) -> dict:
    """Fit the category's template to the batch's prepared models. The fitting is the trainer's
    code (``train.patch_fit``), run as the stage's own process as render runs Blender: the
    dataset side never imports the trainer, and the fit gets one thread of its own. Targets are
    gathered here (labelled as the shard samples are); a model whose input is bad is recorded
    failed here, one whose fit fails is recorded failed there."""
    t0 = time.perf_counter()
    from pipeline.core.errors import ModelError
    from pipeline.core.records import read_record, write_failed
    from pipeline.dataset.shards import fit_target

    category = lst["category"]
    ok, failed = _upstream(s, "prepare", lst, batch)
    fit, prep = s.fit_settings(), s.stage_dir("prepare")
    # The template is read once: the process fits these bytes and the folder is keyed by their
    # fingerprint, so a template edited during the build cannot put one content's fits under
    # another's key.
    prints = template_fingerprints(fit.templates)
    snapshot = template_snapshot(fit.template_for(category), prints)
    stage = Path(s.work_dir) / s.fit_key(prints)
    entries: list[dict] = []
    arrays: dict = {}
    for m in ok:
        folder = model_dir(stage, category, m["work_id"])
        if read_record(folder) is not None:
            continue  # done (ok or failed) by an earlier run
        try:
            pts, ids, names, present = fit_target(
                category, model_dir(prep, category, m["work_id"]), m["model_id"], fit.points, s.seed
            )
        except ModelError as err:
            write_failed(folder, err, category=category, model_id=m["model_id"])
            continue
        arrays[f"points_{len(entries)}"] = pts
        if ids is not None:
            arrays[f"parts_{len(entries)}"] = ids
        path = str(model_dir(prep, category, m["work_id"]) / SAMPLES_FILE)
        entries.append({**{k: m[k] for k in ("model_id", "work_id")}, "path": path, "names": names, "present": present})
    if progress is not None:
        progress(0, len(ok), f"fit {category} batch {batch}: fitting {len(entries)} models")
    answer = _run_fit_job(s, category, entries, arrays, stage, snapshot) if entries else {"cpu_seconds": 0.0}
    outcomes = failed + [_outcome(m, "fit", read_record(model_dir(stage, category, m["work_id"]))) for m in ok]
    if progress is not None:
        progress(len(ok), len(ok), f"fit {category} batch {batch}: done")
    # The fit key holds the template files' content, read from disk: a template edited while the
    # batch ran changes it, so the batch is marked done where its models went (a re-run then fits
    # it again under the new key), never in a folder that lacks them.
    return _write_batch(
        s,
        "fit",
        lst,
        batch,
        sorted(outcomes, key=lambda m: m["model_id"]),
        t0,
        stage_dir=stage,
        cpu_seconds=answer["cpu_seconds"],
    )


def _run_fit_job(
    s: BuildSettings, category: str, entries: list[dict], arrays: dict, stage: Path, snapshot: bytes | None
) -> dict:
    """Hand the batch to ``python -m train.patch_fit`` in a job folder of its own (its records go
    to ``stage``, the fit stage's folder); its answer. ``snapshot``: the template file's bytes as
    the stage's key saw them, which the process loads instead of the file (None: a built-in)."""
    import shutil
    import subprocess
    import sys
    import tempfile

    import numpy as np

    from pipeline.core.schema import FIT_JOB_FILE, FIT_RESULT_FILE, FIT_TARGETS_FILE, FIT_TEMPLATE_FILE
    from pipeline.core.stage_keys import settings_dict

    (stage / category).mkdir(parents=True, exist_ok=True)
    job_dir = Path(tempfile.mkdtemp(prefix="_job-", dir=stage / category))
    try:
        np.savez(job_dir / FIT_TARGETS_FILE, **arrays)
        if snapshot is not None:  # the job folder is scratch: a plain write
            (job_dir / FIT_TEMPLATE_FILE).write_bytes(snapshot)
        job = {
            "category": category,
            "template": s.fit_settings().template_for(category),
            **({"template_file": FIT_TEMPLATE_FILE} if snapshot is not None else {}),
            "settings": settings_dict(s.fit_settings()),
            "seed": s.seed,
            "stage_dir": str(stage),
            "models": entries,
        }
        write_json(job_dir / FIT_JOB_FILE, job)
        root = str(Path(__file__).resolve().parents[1])
        env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
        proc = subprocess.run(
            [sys.executable, "-m", "train.patch_fit", str(job_dir / FIT_JOB_FILE)],
            env=env,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
        )
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
            raise RuntimeError(f"fit stage process for {category} exited with {proc.returncode}: {tail[0]}")
        return read_json(job_dir / FIT_RESULT_FILE)
    finally:
        shutil.rmtree(job_dir, ignore_errors=True)


def fit_results(s: BuildSettings, lst: dict) -> tuple[dict[str, tuple], list[dict]]:
    """The fit stage's results of a category, by work id: (parameters, FIT_MEMBER fields); and
    the models it failed, as the shard step lists failures."""
    import numpy as np

    from pipeline.core.schema import FIT_FIELDS, FIT_PARAMS_FILE

    good: dict[str, tuple] = {}
    bad: list[dict] = []
    for b in range(n_batches(len(lst["models"]), s.batch_size)):
        for m in read_json(batch_path(s, "fit", lst, b))["models"]:
            if m["stage"] != "fit":
                continue  # failed upstream: the augment batches carry it too
            folder = model_dir(s.stage_dir("fit"), lst["category"], m["work_id"])
            if m["status"] == "ok":
                try:
                    rec = read_json(folder / RECORD)
                    good[m["work_id"]] = (np.load(folder / FIT_PARAMS_FILE), {k: rec[k] for k in FIT_FIELDS})
                    continue
                except (OSError, ValueError, KeyError) as exc:
                    m = {**m, "error": {"path": str(folder), "reason": f"fit result unreadable: {exc}"}}
            bad.append(
                {
                    "model_id": m["model_id"],
                    "work_id": m["work_id"],
                    "stage": "fit",
                    "path": s.portable_path(m["error"].get("path")),
                    "reason": m["error"].get("reason"),
                }
            )
    return good, bad


def fit_summary(category: str, result: ShardSet, fits: dict[str, tuple], work_ids: dict[str, str]) -> dict:
    """What category.json records of the fit stage: the template and the mean L_Ch of the
    template and of the fits over the models built (CPU time stays in the work folder: it
    differs between equal builds, the manifest must not)."""
    from pipeline.core.schema import sample_key

    built = {k for infos in result.shards.values() for i in infos for k in i.keys}
    infos = [fits[w][1] for mid, w in sorted(work_ids.items()) if sample_key(category, mid) in built and w in fits]
    if not infos:
        return {"models": 0}
    return {
        "models": len(infos),
        "template": infos[0]["template"],
        "template_sha256": infos[0]["template_sha256"],
        **{k: infos[0][k] for k in ("steps", "lr", "points")},
        "chamfer_template": round(sum(i["chamfer_template"] for i in infos) / len(infos), 7),
        "chamfer_fitted": round(sum(i["chamfer_fitted"] for i in infos) / len(infos), 7),
    }


def listing_field(s: BuildSettings, lst: dict) -> str | None:
    """What the category fragment records of the source list: its key for file sources (so a
    changed folder makes the category stale); nothing for the procedural source, fixed by seed."""
    return None if s.is_procedural else lst["key"]


def shards_step(s: BuildSettings, lst: dict, progress: Progress = None) -> dict:
    """Write the category's shards and its manifest fragment from the augment batch results."""
    t0 = time.perf_counter()
    category = lst["category"]
    n = len(lst["models"])
    ok: list[dict] = []
    failed: list[dict] = []
    for b in range(n_batches(n, s.batch_size)):
        good, bad = _upstream(s, "augment", lst, b)
        ok += good
        failed += [
            {
                "model_id": m["model_id"],
                "stage": m["stage"],
                "path": s.portable_path(m["error"].get("path")),
                "reason": m["error"].get("reason"),
            }
            for m in bad
        ]
    fits: dict[str, tuple] = {}
    if s.fit_patches:  # a model the fit failed is a failed model, as at any other stage
        fits, fit_failed = fit_results(s, lst)
        fit_failed = [f for f in fit_failed if f["work_id"] in {m["work_id"] for m in ok}]
        ok = [m for m in ok if m["work_id"] in fits]
        failed += [{k: v for k, v in f.items() if k != "work_id"} for f in fit_failed]
    dirs = [
        ModelDirs(
            m["model_id"],
            model_dir(s.stage_dir("prepare"), category, m["work_id"]),
            model_dir(s.stage_dir("render"), category, m["work_id"]),
            model_dir(s.stage_dir("augment"), category, m["work_id"]),
            fits.get(m["work_id"]),
        )
        for m in ok
    ]
    if progress is not None:
        progress(0, 1, f"shards {category}: packing {len(dirs)} models")
    holder: dict = {}

    def fragment(result) -> None:
        holder["fragment"] = category_fragment(
            category,
            result,
            s.manifest_settings(),
            s.category_settings_hash(),
            n,
            failed,
            listing=listing_field(s, lst),
            fit=fit_summary(category, result, fits, {m["model_id"]: m["work_id"] for m in ok})
            if s.fit_patches
            else None,
        )
        write_fragment(Path(s.dataset_dir) / category, holder["fragment"])

    cat_dir = Path(s.dataset_dir) / category
    try:
        result = write_category_shards(
            category,
            dirs,
            cat_dir,
            s.shard_settings(),
            s.seed,
            s.shards_key(),
            s.portable_path,
            before_cleanup=fragment,
        )
    except OSError as exc:  # tar writes bypass pipeline.core.atomic: name the folder and the problem
        raise storage_error(cat_dir, exc) from exc
    write_json(s.stage_dir("shards") / category / "_timing.json", {"seconds": round(time.perf_counter() - t0, 3)})
    if progress is not None:
        progress(1, 1, f"shards {category}: {len(result.written)} shard(s) written, {len(result.removed)} removed")
    return holder["fragment"]


def record_run(s: BuildSettings, task_id: str, event: str) -> Path:
    """Note that this process started/finished ``task_id``: one file per (task, host, process)
    under ``<work>/_runs/<task_id>/`` (separate files, not appends, so it is safe on NFS).
    Lets a multi-worker build be audited: which worker ran which batch, and how often."""
    path = Path(s.work_dir) / RUNS / task_id / f"{socket.gethostname()}-{os.getpid()}.json"
    doc = (
        read_json(path)
        if path.exists()
        else {"task": task_id, "host": socket.gethostname(), "pid": os.getpid(), "events": []}
    )
    doc["events"].append({"event": event, "time": round(time.time(), 3)})
    write_json(path, doc)
    return path


def read_runs(work_dir: Path) -> dict[str, list[dict]]:
    """Every recorded run under ``<work>/_runs``, by task id."""
    out: dict[str, list[dict]] = {}
    for p in sorted((Path(work_dir) / RUNS).glob("*/*.json")):
        out.setdefault(p.parent.name, []).append(read_json(p))
    return out


def category_builds(s: BuildSettings, listings: list[dict]) -> list[tuple[BuildSettings, dict]]:
    """Each category list with the settings it is built with (``--preset per-category``: its own)."""
    return [(s.for_category(lst["category"]), lst) for lst in listings]


# The stages that run per batch of models, in build order (BuildSettings.stages)
BATCH_STAGES = ("prepare", "render", "augment", "fit")


def batch_stages(s: BuildSettings) -> tuple[str, ...]:
    """The batch stages this build runs (the fit stage only with --fit-patches)."""
    return tuple(stage for stage in s.stages() if stage in BATCH_STAGES)


def stages_of(builds: list[tuple[BuildSettings, dict]]) -> tuple[str, ...]:
    """The batch stages any of these categories runs, in build order (the fit stage where one
    category's preset fits and another's does not)."""
    runs = {stage for cs, _ in builds for stage in batch_stages(cs)}
    return tuple(stage for stage in BATCH_STAGES if stage in runs)


def stage_seconds(s: BuildSettings, listings: list[dict]) -> dict[str, float]:
    """Wall seconds spent per stage by the batch tasks of these category lists (from _batches/)."""
    builds = category_builds(s, listings)
    out = {}
    for stage in stages_of(builds):
        out[stage] = sum(
            read_json(p).get("seconds", 0.0)
            for cs, lst in builds
            if stage in batch_stages(cs)
            for b in range(n_batches(len(lst["models"]), cs.batch_size))
            for p in [batch_path(cs, stage, lst, b)]
            if p.exists()
        )
    out["shards"] = sum(
        read_json(p)["seconds"]
        for cs, lst in builds
        for p in [cs.stage_dir("shards") / lst["category"] / "_timing.json"]
        if p.exists()
    )
    return out


def category_problems(s: BuildSettings, lst: dict, checksums: bool = False) -> list[str]:
    """Why the dataset folder's copy of this category differs from what this build writes
    ([] = current): settings or source list changed, category.json altered, a listed shard
    missing or of another size, an unlisted shard file present. A shard's sha256 is checked when
    ``checksums`` is set, or when the shard is newer than category.json (edited after the build)."""
    cat_dir = Path(s.dataset_dir) / lst["category"]
    try:
        frag = read_fragment(cat_dir)
    except (OSError, ValueError) as exc:
        return [f"{FRAGMENT} unreadable: {exc}"]
    if frag is None:
        return [f"no {FRAGMENT}"]
    if frag.get("checksum") != content_checksum(frag):
        return [f"{FRAGMENT} altered (checksum does not match its content)"]
    if frag.get("settings_hash") != s.category_settings_hash():
        return ["built with other settings"]
    if frag.get("listing") != listing_field(s, lst):
        return ["source folder changed"]
    frag_mtime = (cat_dir / FRAGMENT).stat().st_mtime_ns
    problems = []
    listed = set()
    for split in frag["splits"].values():
        for sh in split["shards"]:
            listed.add(sh["name"])
            path = cat_dir / sh["name"]
            try:
                st = path.stat()
            except OSError:
                problems.append(f"{sh['name']} missing")
                continue
            if stat.S_ISDIR(st.st_mode):
                problems.append(f"{sh['name']} is a folder")
            elif st.st_size != sh["bytes"]:
                problems.append(f"{sh['name']} has {st.st_size} bytes, category.json says {sh['bytes']}")
            elif (checksums or st.st_mtime_ns > frag_mtime) and file_sha256(path) != sh["sha256"]:
                problems.append(f"{sh['name']} sha256 differs from category.json")
    problems += [f"{p.name} not listed in {FRAGMENT}" for p in list_shards(cat_dir) if p.name not in listed]
    return problems


def manifest_is_current(s: BuildSettings, listings: list[dict], checksums: bool = False) -> bool:
    """Are these categories current, none of the source's gone, and manifest.json exactly the
    merge of the fragments present?"""
    if any(category_problems(cs, lst, checksums) for cs, lst in category_builds(s, listings)) or gone_categories(s):
        return False
    try:
        return read_manifest(Path(s.dataset_dir)) == build_manifest(Path(s.dataset_dir))
    except (OSError, ValueError):
        return False


class TooManyFailures(RuntimeError):
    """More than --max-failed-fraction of a category's models failed (the dataset is written)."""


def too_many_failures(s: BuildSettings, categories: list[str], fraction: float) -> list[str]:
    """One line per category whose failed share exceeds ``fraction``, or that built no model at
    all ([] = none). An empty category is never a success, whatever the fraction: its shards
    would hold nothing and `verify` would find nothing wrong with them."""
    out = []
    for c in categories:
        frag = read_fragment(Path(s.dataset_dir) / c)
        if frag is None:
            continue
        failed, requested = frag["models_failed"], frag["models_requested"]
        share = failed / requested if requested else 0.0
        if share > fraction:
            out.append(
                f"{c}: {failed} of {requested} models failed ({100 * share:.0f}%) > --max-failed-fraction {fraction:g}"
            )
        elif not frag["models_built"]:
            out.append(
                f"{c}: no model built, {failed} of {requested} models failed"
                if requested
                else f"{c}: no model built, the source has none"
            )
    return out


def gone_categories(s: BuildSettings) -> list[str]:
    """Categories in the dataset folder built from this source (same source name in their
    category.json) that the source no longer has: removed or renamed since."""
    from pipeline.sources.layouts import layout_of

    layout = layout_of(s.source)
    offered = set(layout.categories(s.source)) | set(layout.also_accepts(s.source))
    source = s.manifest_settings()["source"]
    out = []
    for frag_path in sorted(Path(s.dataset_dir).glob(f"*/{FRAGMENT}")):
        try:
            frag = read_fragment(frag_path.parent)
        except (OSError, ValueError):
            continue  # unreadable: not provably ours, left alone (verify names it)
        name = frag_path.parent.name
        if (frag or {}).get("settings", {}).get("source") == source and name not in offered:
            out.append(name)
    return out


def manifest_step(s: BuildSettings) -> dict:
    """Retire the source's gone categories (their listed shards and category.json), then merge
    manifest.json from the fragments left, so its categories and totals are the source's."""
    for name in gone_categories(s):
        retire_category(Path(s.dataset_dir) / name)
    return write_manifest(Path(s.dataset_dir))
