"""Watertight envelope resolution vs prepare cost vs how far the envelope sits from the source.

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_envelope.py [--per-category 4]
        [--configs 5000:50000:0,2500:50000:0.9] [--out bench/results/envelope.json]

For each ``resolution:max_faces:pull`` triple it runs prepare's repair steps (Manifold envelope,
the pull back to the source, decimation, clean-up: ``pipeline.prepare.watertight``) on the same
corpus as ``bench_pipeline.py`` (its first ``--per-category`` models of each category) and reports
the CPU seconds of each step per model and the envelope's distance to the source surface, in
units of the model's half-diagonal (the unit-sphere radius prepare normalizes to): mean and 95th
percentile from 20k envelope samples to 60k source samples. The samples training learns from lie
on the envelope, so this distance is how much the target shapes are inflated. Also: how well the
envelope's normals agree with the source face nearest each sample (mean |cos|), and the bodies
it keeps (parts fused by a coarse octree lose their gap).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import point_cloud_utils as pcu
import trimesh
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_pipeline import write_corpus  # noqa: E402  (this folder is on the path when run as a script)

from pipeline.core.atomic import write_json  # noqa: E402
from pipeline.prepare.watertight import clean_solid, decimate, make_watertight, pull_to_source  # noqa: E402
from pipeline.sources.mesh_io import load_mesh  # noqa: E402


def measure(path: Path, configs: list[tuple[int, int, float]]) -> list[dict]:
    v, f = load_mesh(path, 1 << 30)
    src = trimesh.Trimesh(v, f, process=False)
    radius = float(np.linalg.norm(src.bounds[1] - src.bounds[0])) / 2
    tree = cKDTree(trimesh.sample.sample_surface(src, 60000, seed=0)[0])
    rows = []
    for resolution, max_faces, pull in configs:
        t0 = time.process_time()
        wv, wf = make_watertight(v, f, resolution, 0)
        t1 = time.process_time()
        wv = pull_to_source(wv, wf, v, f, pull)
        tp = time.process_time()
        dv, df = decimate(wv, wf, max_faces)
        t2 = time.process_time()
        mesh, _ = clean_solid(dv, df, 0.01)
        t3 = time.process_time()
        points, face_index = trimesh.sample.sample_surface(mesh, 20000, seed=1)
        d = tree.query(points)[0] / radius
        nearest = pcu.closest_points_on_mesh(points, np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int32))[1]
        cos = np.abs((mesh.face_normals[face_index] * src.face_normals[nearest]).sum(axis=1))
        rows.append(
            {
                "watertight_s": t1 - t0,
                "pull_s": tp - t1,
                "decimate_s": t2 - tp,
                "clean_s": t3 - t2,
                "distance_mean": float(d.mean()),
                "distance_p95": float(np.percentile(d, 95)),
                "normal_cos": float(cos.mean()),
                "bodies": int(mesh.body_count),
                "envelope_faces": int(len(wf)),
                "faces": int(len(mesh.faces)),
                "watertight": bool(mesh.is_watertight),
            }
        )
    return rows


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--per-category", type=int, default=4)
    ap.add_argument("--configs", default="5000:50000:0,2500:50000:0,2500:50000:0.9,2000:50000:0.9")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_envelope"))
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    configs = [(int(r), int(m), float(p)) for r, m, p in (c.split(":") for c in args.configs.split(","))]
    write_corpus(args.work, args.per_category)
    paths = sorted((args.work / "corpus").glob("*/*.ply"))
    per_model = [measure(p, configs) for p in paths]
    results = []
    for i, (resolution, max_faces, pull) in enumerate(configs):
        rows = [m[i] for m in per_model]
        mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k != "watertight"}
        mean.update(
            resolution=resolution,
            max_faces=max_faces,
            pull_to_source=pull,
            models=len(rows),
            all_watertight=all(r["watertight"] for r in rows),
        )
        results.append(mean)
        cost = mean["watertight_s"] + mean["pull_s"] + mean["decimate_s"] + mean["clean_s"]
        print(
            f"resolution {resolution:5d}, max_faces {max_faces:5d}, pull {pull:.2f}: {cost:.3f} CPU s per model "
            f"(envelope {mean['watertight_s']:.3f}, pull {mean['pull_s']:.3f}, decimate {mean['decimate_s']:.3f}, "
            f"clean {mean['clean_s']:.3f}); envelope to source mean {mean['distance_mean'] * 1000:.1f}, p95 "
            f"{mean['distance_p95'] * 1000:.1f} (x1e-3 radius); normal |cos| {mean['normal_cos']:.3f}; "
            f"{mean['bodies'] * len(rows):.0f} bodies in all; {mean['faces']:.0f} faces; all watertight: "
            f"{mean['all_watertight']}",
            flush=True,
        )
    if args.out:
        write_json(args.out, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
