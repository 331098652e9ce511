"""Benchmark mesh preparation: median seconds per model and peak RSS at 2k, 20k, 200k input faces.

Each size runs in its own subprocess (one thread) so its peak RSS is its own. Inputs are an
airplane-like soup of intersecting parts with holes, tessellated to exactly the requested face
count (full subdivisions, then splitting a subset of faces).

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_prepare.py [--sizes 2000 20000 200000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.core.records import ModelRef  # noqa: E402
from pipeline.prepare.batch import PrepareSettings, prepare_model  # noqa: E402


def soup_with_faces(target: int) -> trimesh.Trimesh:
    """Fuselage + thin wings + tail + cockpit box, overlapping, with holes, exactly ``target`` faces."""
    parts = [
        trimesh.creation.cylinder(
            0.12, 1.6, sections=24, transform=trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])
        ),
        trimesh.creation.box((0.35, 0.015, 1.8)),
        trimesh.creation.box((0.15, 0.4, 0.02), transform=trimesh.transformations.translation_matrix([-0.7, 0.2, 0])),
        trimesh.creation.box((0.3, 0.2, 0.2), transform=trimesh.transformations.translation_matrix([0.5, 0.1, 0])),
    ]
    mesh = trimesh.util.concatenate(parts)
    mesh.update_faces(np.arange(len(mesh.faces)) % 17 != 0)  # holes, like scraped models
    while len(mesh.faces) * 4 <= target:
        mesh = mesh.subdivide()
    extra = (target - len(mesh.faces)) // 3  # splitting one face adds three
    if extra > 0:
        mesh = mesh.subdivide(face_index=np.arange(extra))
    return mesh


def run_one(faces: int, repeats: int) -> dict:
    """Time ``repeats`` preparations of one input in this process; report median and peak RSS."""
    rss_start = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "soup.obj"
        mesh = soup_with_faces(faces)
        mesh.export(src)
        settings = PrepareSettings()
        times, cpu, rec = [], [], None
        for i in range(repeats):
            t, c = time.perf_counter(), time.process_time()
            rec = prepare_model(ModelRef("bench", f"m{i}", src, "folder"), Path(tmp) / f"out{i}", settings)
            times.append(time.perf_counter() - t)
            cpu.append(time.process_time() - c)
    return {
        "input_faces": int(len(mesh.faces)),
        "output_faces": rec["faces"]["output"],
        "watertight_faces": rec["faces"]["watertight"],
        "median_s": statistics.median(times),
        "min_s": min(times),
        # CPU seconds of this (single-threaded) process: robust to other load on a shared box.
        "median_cpu_s": statistics.median(cpu),
        "stages_s": rec["timings"],
        "rss_after_imports_mb": rss_start,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[2000, 20000, 200000])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)  # internal: run one size, print JSON
    args = ap.parse_args()
    if args.one:
        print(json.dumps(run_one(args.one, args.repeats)))
        return
    print(
        f"{'input faces':>12} {'wt faces':>9} {'out faces':>9} {'median s':>9} {'min s':>7} {'median cpu s':>12} {'peak RSS MB':>12}"
    )
    for size in args.sizes:
        out = subprocess.run(
            [sys.executable, __file__, "--one", str(size), "--repeats", str(args.repeats)],
            check=True,
            capture_output=True,
            text=True,
            env={**os.environ, "OMP_NUM_THREADS": "1"},
        )
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(
            f"{r['input_faces']:>12} {r['watertight_faces']:>9} {r['output_faces']:>9} {r['median_s']:>9.3f} "
            f"{r['min_s']:>7.3f} {r['median_cpu_s']:>12.3f} {r['peak_rss_mb']:>12.0f}   (RSS after imports {r['rss_after_imports_mb']:.0f} MB; "
            f"last run stages {r['stages_s']})"
        )


if __name__ == "__main__":
    main()
