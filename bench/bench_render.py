"""Render benchmark: seconds per view (median) at ~2k, 20k and 200k triangles, and the Blender
start-up cost paid once per batch.

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_render.py [--size 256] [--views 8] [--backend embree]

Meshes: a normalized UV sphere (one smooth silhouette) and a procedural car prepared by the
prepare stage, both its watertight envelope (``car``, drawn until the render stage read
lines.ply) and its line mesh (``carsrc``, drawn now), each subdivided or decimated to the target
size (many silhouette, border and crease lines); their ratio is printed per size.
Per-view times come from the worker's own record (scene update + render + PNG/stroke writing).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from render.batch import render_batch  # noqa: E402
from render.sample_meshes import normalized, sphere_with_faces, write_ply  # noqa: E402
from render.settings import BACKENDS, RenderSettings  # noqa: E402

TARGETS = (2_000, 20_000, 200_000)


def subdivided_to(mesh: trimesh.Trimesh, n_faces: int) -> trimesh.Trimesh:
    """Decimate or subdivide (midpoint, 4x per step) toward ``n_faces`` triangles."""
    while len(mesh.faces) < n_faces:
        v, f = trimesh.remesh.subdivide(mesh.vertices, mesh.faces)
        mesh = trimesh.Trimesh(v, f, process=False)
    if len(mesh.faces) > n_faces * 1.5:
        import pymeshlab

        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(mesh.vertices, mesh.faces))
        ms.meshing_decimation_quadric_edge_collapse(targetfacenum=n_faces, preservetopology=True)
        m = ms.current_mesh()
        mesh = trimesh.Trimesh(m.vertex_matrix(), m.face_matrix(), process=False)
    return normalized(mesh)


def car_meshes(work: Path) -> dict[str, trimesh.Trimesh]:
    """A procedural car prepared by the prepare stage: ``car`` its watertight envelope (what the
    render stage drew before it read lines.ply), ``carsrc`` its line mesh (what it draws now)."""
    try:
        from pipeline.core.schema import LINE_MESH_FILE, MESH_FILE
        from pipeline.prepare.batch import PrepareSettings, prepare_batch
        from pipeline.sources.layouts import list_models
    except ImportError:
        return {}
    refs = list_models("procedural", "car", 1, 0, work)
    rec = prepare_batch(refs, work / "prepare", PrepareSettings())[0]
    if rec["status"] != "ok":
        return {}
    folder = work / "prepare" / "car" / refs[0].model_id
    return {
        name: trimesh.load(folder / file, force="mesh", process=False)
        for name, file in (("car", MESH_FILE), ("carsrc", LINE_MESH_FILE))
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--flat", action="store_true", help="flat shading (smooth_shading=False)")
    ap.add_argument("--backend", default="freestyle", choices=BACKENDS)
    args = ap.parse_args()
    settings = RenderSettings(
        image_size=args.size, views=args.views, smooth_shading=not args.flat, backend=args.backend
    )
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        cars = car_meshes(work)
        items_by_target = {}
        for n in TARGETS:
            items = [(f"sphere_{n}", write_ply(sphere_with_faces(n), work / "in" / f"sphere_{n}.ply"))]
            for name, car in cars.items():
                items.append((f"{name}_{n}", write_ply(subdivided_to(car, n), work / "in" / f"{name}_{n}.ply")))
            items_by_target[n] = items

        # start-up: launch → the worker's "... ready in" progress message, one batch per target size
        startups = []
        print(
            f"backend {settings.backend}, image {args.size}², {args.views} views per model, threads={settings.threads},"
            f" smooth_shading={settings.smooth_shading}"
        )
        for n, items in items_by_target.items():
            t0 = time.perf_counter()
            marks: list[float] = []
            load_before = os.getloadavg()[0]

            def progress(done, total, message, marks=marks):
                if " ready in " in message:
                    marks.append(time.perf_counter() - t0)
                    print(f"  worker: {message}")

            recs = render_batch("bench", items, work / "stage", settings, 0, progress)
            wall = time.perf_counter() - t0
            startups += marks
            for (mid, _), rec in zip(items, recs):
                assert rec["status"] == "ok", rec
                views, cpu = rec["timings"]["views_s"], rec["timings"]["views_cpu_s"]
                print(
                    f"{mid:>14}: {rec['mesh']['n_faces']:>7} triangles  median {statistics.median(views):.3f} s/view"
                    f" wall, {statistics.median(cpu):.3f} s/view CPU (min {min(cpu):.3f}, max {max(cpu):.3f}),"
                    f" load {rec['timings']['load_s']:.3f} s, strokes/view {np.mean(rec['n_strokes']):.0f}"
                )
            cpu = {mid: statistics.median(rec["timings"]["views_cpu_s"]) for (mid, _), rec in zip(items, recs)}
            if f"car_{n}" in cpu and f"carsrc_{n}" in cpu:
                print(f"  line mesh / envelope CPU per view at {n}: {cpu[f'carsrc_{n}'] / cpu[f'car_{n}']:.2f}")
            print(f"  batch wall {wall:.2f} s (1-min load average before: {load_before:.1f} on {os.cpu_count()} cores)")
        print(f"start-up per batch (launch → worker ready): median {statistics.median(startups):.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
