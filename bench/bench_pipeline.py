"""Pipeline cost per model, per stage, for both contour backends, and the embree backend against
Freestyle per view (time and stroke F1 per category).

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_pipeline.py [--per-category 13] [--views 8]
        [--variants 4] [--work DIR] [--out bench/results/pipeline.md]

Corpus (fixed, seeded): ``--per-category`` procedural models of each of the 8 categories, written
as a folder source; every third one is midpoint-subdivided once and every sixth twice (4x and 16x
the faces), so inputs range from ~1k to ~100k+ triangles. The build runs the real stage functions
of the Luigi tasks (workflows.steps: prepare, render, augment, shards) batch by batch in this
process; a stage's cost is the CPU time of this process and of its finished child processes
(``resource.getrusage`` SELF + CHILDREN, user + system) over that stage, which stays meaningful
on a shared machine where wall time does not. The prepare stage is shared by both backends (same
stage key), so it runs and is counted once. Per-view times come from the render records
(``views_cpu_s``; the per-model set-up ``load_s`` is shown apart and amortized). Imports and
numba compilation are done before measuring: a long-lived Luigi worker pays them once.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from augment.metrics import stroke_scores  # noqa: E402
from pipeline.core.atomic import read_json, write_json  # noqa: E402
from pipeline.core.records import model_dir  # noqa: E402
from pipeline.shapes import CATEGORIES  # noqa: E402
from workflows import steps  # noqa: E402
from workflows.build_settings import BuildSettings  # noqa: E402
from workflows.listing import current_listing  # noqa: E402

SHAPENET_MODELS = 12_721  # ShapeNet Core v2, the 8 categories


def cpu_seconds() -> float:
    """CPU time of this process plus its waited-for children so far."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def write_corpus(root: Path, per_category: int, seed: int = 0) -> dict[str, int]:
    """The fixed corpus as ``<root>/<category>/<id>.ply``; returns triangles per model id."""
    import trimesh

    from pipeline.sources.layouts import list_models

    faces = {}
    for cat in CATEGORIES:
        refs = list_models("procedural", cat, per_category, seed, root / "_procedural")
        for k, ref in enumerate(refs):
            out = root / "corpus" / cat / f"{ref.model_id}.ply"
            mesh = trimesh.load(ref.path, force="mesh", process=False)
            for _ in range((k % 3 == 2) + (k % 6 == 5)):
                v, f = trimesh.remesh.subdivide(mesh.vertices, mesh.faces)
                mesh = trimesh.Trimesh(v, f, process=False)
            if not out.exists():
                out.parent.mkdir(parents=True, exist_ok=True)
                mesh.export(out)
            faces[f"{cat}/{ref.model_id}"] = len(mesh.faces)
    return faces


def run_stage(s: BuildSettings, stage: str, lists: dict[str, dict]) -> float:
    """Run one stage over every batch of every category; its CPU seconds."""
    c0 = cpu_seconds()
    for cat in CATEGORIES:
        for b in range(steps.n_batches(len(lists[cat]["models"]), s.batch_size)):
            t = time.perf_counter()
            doc = getattr(steps, f"{stage}_step")(s, lists[cat], b)
            bad = [m for m in doc["models"] if m["status"] != "ok" and m["stage"] == stage]
            print(
                f"  {stage:8s} {cat:9s} batch {b}: {len(doc['models']) - len(bad)} ok, {len(bad)} failed,"
                f" {time.perf_counter() - t:.1f} s wall",
                flush=True,
            )
    if stage == "augment":
        for cat in CATEGORIES:
            steps.shards_step(s, lists[cat])
    return cpu_seconds() - c0


def view_figures(s: BuildSettings, lists: dict[str, dict]) -> dict:
    """Per-view CPU seconds and per-model set-up from the render records."""
    views, loads, n_views = [], [], []
    for cat in CATEGORIES:
        for m in lists[cat]["models"]:
            rec = read_json(model_dir(s.stage_dir("render"), cat, m["work_id"]) / "record.json")
            if rec.get("status") == "ok":
                views += rec["timings"]["views_cpu_s"]
                loads.append(rec["timings"]["load_s"])
                n_views.append(len(rec["timings"]["views_cpu_s"]))
    return {
        "view_cpu_median": statistics.median(views),
        "load_median": statistics.median(loads),
        "per_view_with_setup": statistics.median(views) + statistics.median(loads) / statistics.median(n_views),
    }


def f1_per_category(fs: BuildSettings, em: BuildSettings, lists: dict[str, dict]) -> dict[str, list[float]]:
    """Stroke F1 (2 px) of every embree view against Freestyle's, by category."""
    out: dict[str, list[float]] = {}
    for cat in CATEGORIES:
        for m in lists[cat]["models"]:
            a = model_dir(fs.stage_dir("render"), cat, m["work_id"]) / "strokes.json"
            b = model_dir(em.stage_dir("render"), cat, m["work_id"]) / "strokes.json"
            if not (a.exists() and b.exists()):
                continue
            da, db = read_json(a), read_json(b)
            for va, vb in zip(da["views"], db["views"]):
                got = [np.asarray(x["points"], float) for x in vb]
                want = [np.asarray(x["points"], float) for x in va]
                out.setdefault(cat, []).append(stroke_scores(got, want, da["image_size"], tol=2.0)["f1"])
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--per-category", type=int, default=13)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--variants", type=int, default=4)
    ap.add_argument("--batch-size", type=int, default=16)
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_pipeline"))
    ap.add_argument("--backends", default="embree,freestyle")
    ap.add_argument(
        "--prepare-settings",
        default="{}",
        help="prepare overrides as JSON, e.g. '{\"resolution\": 2000}' (bench_envelope.py)",
    )
    ap.add_argument("--out", type=Path, default=None, help="also write the figures as JSON here")
    args = ap.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    args.work.mkdir(parents=True, exist_ok=True)
    # one-time costs of a long-lived worker process (imports, numba compilation) are not per model
    from workflows.warm import warm_stage_code

    warm_stage_code()
    faces = write_corpus(args.work, args.per_category)
    sizes = sorted(faces.values())
    print(
        f"corpus: {len(faces)} models, triangles min {sizes[0]}, median {sizes[len(sizes) // 2]}, max {sizes[-1]};"
        f" {args.views} views x {args.variants} variants; load average {os.getloadavg()[0]:.1f} on"
        f" {os.cpu_count()} cores",
        flush=True,
    )

    def settings(backend: str) -> BuildSettings:
        return BuildSettings(
            source=str(args.work / "corpus"),
            models_per_category=0,
            views=args.views,
            variants=args.variants,
            render_overrides=json.dumps({"backend": backend}),
            prepare_overrides=args.prepare_settings,
            work_dir=args.work / "work",
            dataset_dir=args.work / f"ds-{backend}",
            batch_size=args.batch_size,
        )

    backends = args.backends.split(",")
    first = settings(backends[0])
    lists = {cat: current_listing(first, cat) for cat in CATEGORIES}
    total = sum(len(lst["models"]) for lst in lists.values())
    prepare_s = run_stage(first, "prepare", lists)
    n_ok = sum(
        1
        for cat in CATEGORIES
        for m in lists[cat]["models"]
        if (read_json(model_dir(first.stage_dir("prepare"), cat, m["work_id"]) / "record.json") or {}).get("status")
        == "ok"
    )
    results = {
        "models": total,
        "prepared_ok": n_ok,
        "views": args.views,
        "variants": args.variants,
        "prepare_settings": json.loads(args.prepare_settings),
        "triangles": {"min": sizes[0], "median": sizes[len(sizes) // 2], "max": sizes[-1]},
        "prepare_core_s_per_model": prepare_s / total,
        "backends": {},
    }
    print(f"prepare: {prepare_s:.1f} core-s, {prepare_s / total:.3f} per model ({n_ok}/{total} ok)", flush=True)
    if n_ok < total:  # a cost per model of failed models measures the failure, not the pipeline
        print(f"error: {total - n_ok} of {total} corpus models failed prepare (their record.json says why)")
        return 1
    for backend in backends:
        s = settings(backend)
        render_s = run_stage(s, "render", lists)
        augment_s = run_stage(s, "augment", lists)  # includes the category shards
        per = {"prepare": prepare_s / total, "render": render_s / total, "augment+shards": augment_s / total}
        per["all"] = sum(per.values())
        per["shapenet_core_hours"] = per["all"] * SHAPENET_MODELS / 3600
        per.update(view_figures(s, lists))
        results["backends"][backend] = per
        print(f"{backend}: " + ", ".join(f"{k} {v:.3f}" for k, v in per.items()), flush=True)
    if {"embree", "freestyle"} <= set(backends):
        f1 = f1_per_category(settings("freestyle"), settings("embree"), lists)
        results["f1"] = {
            cat: {"views": len(v), "median": statistics.median(v), "min": min(v), "mean": float(np.mean(v))}
            for cat, v in f1.items()
        }
        fs, em = results["backends"]["freestyle"], results["backends"]["embree"]
        results["speedup_per_view"] = fs["view_cpu_median"] / em["view_cpu_median"]
        results["speedup_per_view_with_setup"] = fs["per_view_with_setup"] / em["per_view_with_setup"]
        for cat, v in results["f1"].items():
            print(f"F1 {cat:9s} median {v['median']:.3f} min {v['min']:.3f} mean {v['mean']:.3f} ({v['views']} views)")
        print(
            f"per view: freestyle {fs['view_cpu_median'] * 1000:.1f} ms CPU, embree {em['view_cpu_median'] * 1000:.1f} ms"
            f" ({results['speedup_per_view']:.1f}x); with the embree set-up amortized over the views"
            f" {em['per_view_with_setup'] * 1000:.1f} ms ({results['speedup_per_view_with_setup']:.1f}x)"
        )
    results["load_average_end"] = os.getloadavg()[0]
    if args.out:
        write_json(args.out, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
