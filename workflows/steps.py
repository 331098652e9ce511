"""What each Luigi task does, as plain functions (no Luigi here), so they can be called and
tested directly. Each batch step writes a small JSON listing its models' outcomes:

``{"stage", "category", "batch", "models": [{"model_id", "status", "stage", "error"?}]}``

A model that failed upstream is carried forward with the stage where it failed, so the shard
step sees every failure of the category with its reason.
"""

from __future__ import annotations

import itertools
import os
import shutil
import socket
import time
from pathlib import Path

from pipeline.atomic import read_json, storage_error, write_json
from pipeline.build_settings import BuildSettings
from pipeline.layout import ModelRef, Progress, model_dir
from pipeline.manifest import category_fragment, read_fragment, write_fragment, write_manifest
from pipeline.shards import ModelDirs, write_category_shards

BATCHES = "_batches"
LISTS = "_lists"
RUNS = "_runs"


# ---------------------------------------------------------------- paths

def list_path(s: BuildSettings, category: str) -> Path:
    """The category's model list for this limit (adding models makes a new list)."""
    tag = f"n{s.limit}" if s.limit is not None else "all"
    return s.stage_dir("source") / category / LISTS / f"{tag}.json"


def batch_path(s: BuildSettings, stage: str, category: str, batch: int) -> Path:
    """A batch's outcome file; named by limit and batch size too, since both change which models
    batch number ``batch`` holds."""
    tag = f"n{s.limit}" if s.limit is not None else "all"
    return s.stage_dir(stage) / category / BATCHES / f"{tag}-b{s.batch_size}-{batch:05d}.json"


def read_list(s: BuildSettings, category: str) -> list[ModelRef]:
    return [ModelRef(category, m["model_id"], Path(m["path"]), m["source"])
            for m in read_json(list_path(s, category))["models"]]


def expected_models(s: BuildSettings, category: str) -> int:
    """How many models the category's list holds (or will hold once written), without generating
    or opening any mesh: the written list if there is one, else the procedural count, else the
    directory listing (names only)."""
    if list_path(s, category).exists():
        return len(read_list(s, category))
    from pipeline.sources import DEFAULT_PROCEDURAL_COUNT, iter_models

    if s.is_procedural:
        return s.limit if s.limit is not None else DEFAULT_PROCEDURAL_COUNT
    names = iter_models(s.source, category)
    return sum(1 for _ in (names if s.limit is None else itertools.islice(names, s.limit)))


def n_batches(n_models: int, batch_size: int) -> int:
    return -(-n_models // batch_size)


# ---------------------------------------------------------------- steps

def write_source_list(s: BuildSettings, category: str) -> int:
    """List (and for the procedural source, generate) the category's models; returns the count."""
    from pipeline.sources import list_models

    refs = list_models(s.source, category, s.limit, s.seed, Path(s.work_dir))
    write_json(list_path(s, category), {
        "category": category,
        "models": [{"model_id": r.model_id, "path": str(r.path), "source": r.source} for r in refs],
    })
    return len(refs)


def _outcome(model_id: str, stage: str, rec: dict | None) -> dict:
    if rec is None:
        return {"model_id": model_id, "status": "failed", "stage": stage,
                "error": {"path": model_id, "reason": "no record written"}}
    out = {"model_id": model_id, "status": rec.get("status", "failed"), "stage": stage}
    if out["status"] != "ok":
        out["error"] = rec.get("error") or {"path": model_id, "reason": "unknown failure"}
    return out


def _write_batch(s: BuildSettings, stage: str, category: str, batch: int, outcomes: list[dict],
                 t0: float, **extra) -> dict:
    # wall seconds are kept in the work folder only (never in shards or manifest) for stage shares
    doc = {"stage": stage, "category": category, "batch": batch, "models": outcomes,
           "seconds": round(time.perf_counter() - t0, 3), **extra}
    write_json(batch_path(s, stage, category, batch), doc)
    return doc


def _upstream(s: BuildSettings, stage: str, category: str, batch: int) -> tuple[list[str], list[dict]]:
    """Model ids that passed ``stage`` in this batch, and the outcomes of those that did not."""
    doc = read_json(batch_path(s, stage, category, batch))
    ok = [m["model_id"] for m in doc["models"] if m["status"] == "ok"]
    return ok, [m for m in doc["models"] if m["status"] != "ok"]


def prepare_step(s: BuildSettings, category: str, batch: int, progress: Progress = None) -> dict:
    t0 = time.perf_counter()
    from pipeline.prepare import prepare_batch

    refs = read_list(s, category)[batch * s.batch_size:(batch + 1) * s.batch_size]
    records = prepare_batch(refs, s.stage_dir("prepare"), s.prepare_settings(), progress)
    return _write_batch(s, "prepare", category, batch,
                        [_outcome(r.model_id, "prepare", rec) for r, rec in zip(refs, records)], t0)


def render_step(s: BuildSettings, category: str, batch: int, progress: Progress = None,
                crash_retries: int = 1) -> dict:
    """Render the batch's prepared models in one Blender process. If Blender crashes or hangs,
    the batch is retried ``crash_retries`` times (finished models keep their records, so a retry
    resumes); after that the models still unrendered are recorded failed with the cause."""
    t0 = time.perf_counter()
    from render.batch import RenderBatchError, render_batch

    ok, failed = _upstream(s, "prepare", category, batch)
    prep = s.stage_dir("prepare")
    from pipeline.prepare import LINE_MESH_FILE  # the source's surface: its sharp edges are drawn

    items = [(mid, model_dir(prep, category, mid) / LINE_MESH_FILE) for mid in ok]
    records: list[dict] = []
    crashes: list[str] = []
    for attempt in range(crash_retries + 1 if items else 0):
        try:
            records = render_batch(category, items, s.stage_dir("render"), s.render_settings(), s.seed,
                                   progress, on_crash="record" if attempt == crash_retries else "raise")
            break
        except RenderBatchError as exc:
            crashes.append(str(exc))
            if progress is not None:
                progress(0, len(items), f"render {category} batch {batch}: retry {attempt + 1}/{crash_retries} after: {exc}"[:300])
    outcomes = failed + [_outcome(mid, "render", rec) for (mid, _), rec in zip(items, records)]
    return _write_batch(s, "render", category, batch, sorted(outcomes, key=lambda m: m["model_id"]), t0,
                        attempts=len(crashes) + bool(records), crashes=crashes)


def augment_step(s: BuildSettings, category: str, batch: int, progress: Progress = None) -> dict:
    t0 = time.perf_counter()
    from augment.batch import augment_batch

    ok, failed = _upstream(s, "render", category, batch)
    rend = s.stage_dir("render")
    items = [(mid, model_dir(rend, category, mid)) for mid in ok]
    records = augment_batch(category, items, s.stage_dir("augment"), s.augment_settings(), s.seed, progress) if items else []
    outcomes = failed + [_outcome(mid, "augment", rec) for (mid, _), rec in zip(items, records)]
    return _write_batch(s, "augment", category, batch, sorted(outcomes, key=lambda m: m["model_id"]), t0)


def shards_step(s: BuildSettings, category: str, progress: Progress = None) -> dict:
    """Write the category's shards and its manifest fragment from the augment batch results."""
    t0 = time.perf_counter()
    n = len(read_list(s, category))
    ok: list[str] = []
    failed: list[dict] = []
    for b in range(n_batches(n, s.batch_size)):
        good, bad = _upstream(s, "augment", category, b)
        ok += good
        failed += [{"model_id": m["model_id"], "stage": m["stage"],
                    "path": s.portable_path(m["error"].get("path")), "reason": m["error"].get("reason")}
                   for m in bad]
    dirs = [ModelDirs(mid, model_dir(s.stage_dir("prepare"), category, mid),
                      model_dir(s.stage_dir("render"), category, mid),
                      model_dir(s.stage_dir("augment"), category, mid)) for mid in ok]
    if progress is not None:
        progress(0, 1, f"shards {category}: packing {len(dirs)} models")
    holder: dict = {}

    def fragment(result) -> None:
        holder["fragment"] = category_fragment(category, result, s.manifest_settings(),
                                               s.category_settings_hash(), n, failed)
        write_fragment(Path(s.dataset_dir) / category, holder["fragment"])

    cat_dir = Path(s.dataset_dir) / category
    # A run killed while packing leaves its staging folder behind; only this task (one per
    # category at a time, Luigi guarantees) writes here, so stale ones can go.
    for stale in cat_dir.glob(".staging-*"):
        shutil.rmtree(stale, ignore_errors=True)
    try:
        result = write_category_shards(category, dirs, cat_dir, s.shard_settings(),
                                       s.seed, s.shards_key(), s.portable_path, before_cleanup=fragment)
    except OSError as exc:  # tar writes bypass pipeline.atomic: name the folder and the problem
        raise storage_error(cat_dir, exc) from exc
    write_json(s.stage_dir("shards") / category / "_timing.json", {"seconds": round(time.perf_counter() - t0, 3)})
    if progress is not None:
        progress(1, 1, f"shards {category}: {len(result.written)} shard(s) written, "
                       f"{len(result.removed)} removed")
    return holder["fragment"]


def record_run(s: BuildSettings, task_id: str, event: str) -> Path:
    """Note that this process started/finished ``task_id``: one file per (task, host, process)
    under ``<work>/_runs/<task_id>/`` (separate files, not appends, so it is safe on NFS).
    Lets a multi-worker build be audited: which worker ran which batch, and how often."""
    path = Path(s.work_dir) / RUNS / task_id / f"{socket.gethostname()}-{os.getpid()}.json"
    doc = read_json(path) if path.exists() else {"task": task_id, "host": socket.gethostname(),
                                                  "pid": os.getpid(), "events": []}
    doc["events"].append({"event": event, "time": round(time.time(), 3)})
    write_json(path, doc)
    return path


def read_runs(work_dir: Path) -> dict[str, list[dict]]:
    """Every recorded run under ``<work>/_runs``, by task id."""
    out: dict[str, list[dict]] = {}
    for p in sorted((Path(work_dir) / RUNS).glob("*/*.json")):
        out.setdefault(p.parent.name, []).append(read_json(p))
    return out


def stage_seconds(s: BuildSettings, categories: list[str]) -> dict[str, float]:
    """Wall seconds spent per stage by the batch tasks of these categories (from _batches/)."""
    out = {}
    for stage in ("prepare", "render", "augment"):
        out[stage] = sum(read_json(p).get("seconds", 0.0) for c in categories
                         for p in (s.stage_dir(stage) / c / BATCHES).glob("*.json"))
    out["shards"] = sum(read_json(p)["seconds"] for c in categories
                        for p in [s.stage_dir("shards") / c / "_timing.json"] if p.exists())
    return out


def category_is_current(s: BuildSettings, category: str) -> bool:
    """Does the dataset folder hold this category built with exactly these settings?"""
    frag = read_fragment(Path(s.dataset_dir) / category)
    if frag is None or frag.get("settings_hash") != s.category_settings_hash():
        return False
    return all((Path(s.dataset_dir) / category / sh["name"]).exists()
               for split in frag["splits"].values() for sh in split["shards"])


def manifest_is_current(s: BuildSettings, categories: list[str]) -> bool:
    """Is manifest.json present and listing these categories exactly as their fragments do?"""
    path = Path(s.dataset_dir) / "manifest.json"
    if not path.exists():
        return False
    manifest = read_json(path)
    return all(category_is_current(s, c)
               and manifest["categories"].get(c) == read_fragment(Path(s.dataset_dir) / c)
               for c in categories)


def manifest_step(s: BuildSettings) -> dict:
    return write_manifest(Path(s.dataset_dir))
