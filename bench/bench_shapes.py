"""Time procedural shape generation and CPU thumbnails; prints medians.

OMP_NUM_THREADS=1 .venv/bin/python bench/bench_shapes.py
"""

from __future__ import annotations

import statistics
import time

import numpy as np
import trimesh

from pipeline.core.thumbnails import render_mesh
from pipeline.shapes import CATEGORIES, generate


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.process_time()
        fn()
        times.append(time.process_time() - t)
    return statistics.median(times)


def main() -> None:
    print("generate (median over 10 models, CPU ms) and mean faces per model")
    for cat in CATEGORIES:
        times, faces = [], []
        for i in range(10):
            t = time.process_time()
            m = generate(cat, i, seed=0)
            times.append(time.process_time() - t)
            faces.append(m.n_faces)
        print(f"  {cat:9s} {statistics.median(times) * 1e3:7.1f} ms  {np.mean(faces):7.0f} faces")
    print("render_mesh 256x256 (median of 5, CPU ms: the machine is shared, wall time is noisy)")
    for sub in (4, 5, 6):
        mesh = trimesh.creation.icosphere(subdivisions=sub)
        render_mesh(mesh.vertices, mesh.faces)
        t = median_time(lambda: render_mesh(mesh.vertices, mesh.faces, size=256), 5)
        print(f"  icosphere {len(mesh.faces):6d} faces {t * 1e3:7.1f} ms")
    m = generate("airplane", 0)
    v, f = m.merged()
    t = median_time(lambda: render_mesh(v, f, size=256), 5)
    print(f"  airplane {len(f):6d} faces {t * 1e3:7.1f} ms")


if __name__ == "__main__":
    main()
