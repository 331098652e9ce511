"""Time the augment stage per sketch: vectorize (per view), augment and rasterize (per variant).

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_augment.py [--render-dir WORK/render-<key>]

Without --render-dir, the three small test meshes are rendered once (Blender, 256², 4 views)
into a temporary folder. Prints medians in milliseconds; one core (OMP_NUM_THREADS=1).
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

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from augment.batch import list_views, load_gray  # noqa: E402
from augment.metrics import stroke_scores  # noqa: E402
from augment.pencil import draw_pencil  # noqa: E402
from augment.settings import REFERENCE_SIZE, AugmentSettings  # noqa: E402
from augment.strokes import augment_strokes  # noqa: E402
from augment.variants import reference_strokes  # noqa: E402
from augment.vectorize import vectorize  # noqa: E402
from pipeline.core.atomic import read_json  # noqa: E402
from pipeline.core.seeding import rng_for  # noqa: E402


def render_samples(folder: Path) -> Path:
    from render.batch import render_batch
    from render.sample_meshes import write_samples
    from render.settings import RenderSettings

    items = write_samples(folder / "meshes")
    render_batch("samples", items, folder / "render", RenderSettings(views=4, image_size=256), seed=0)
    return folder / "render"


def timed(fn, *args):
    t = time.perf_counter()
    out = fn(*args)
    return out, (time.perf_counter() - t) * 1e3


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--render-dir", type=Path)
    ap.add_argument("--variants", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    try:
        import torch  # noqa: F401  (only to pin its threads if something imports it)

        torch.set_num_threads(1)
    except ImportError:
        pass

    tmp = None
    render_dir = args.render_dir
    if render_dir is None:
        tmp = tempfile.TemporaryDirectory()
        render_dir = render_samples(Path(tmp.name))
    folders = sorted(p.parent for p in render_dir.glob("*/*/record.json"))
    views = [(f, v, p) for f in folders for v, p in list_views(f)]
    if not views:
        print(f"no views under {render_dir}", file=sys.stderr)
        return 1
    vectorize(load_gray(views[0][2]))  # numba (skan) compiles on first use: not timed

    settings = {
        128: AugmentSettings(variants=args.variants),
        512: AugmentSettings(variants=args.variants, out_size=512),
    }
    t_vec, t_ref, t_aug, t_ras, f1s = [], [], [], {128: [], 512: []}, []
    by_cat: dict[str, list[dict]] = {}
    for rep in range(args.repeats):
        for folder, v, path in views:
            gray = load_gray(path)
            strokes, ms = timed(vectorize, gray)
            t_vec.append(ms)
            if rep == 0 and (folder / "strokes.json").exists():
                cap = [np.asarray(s["points"]) for s in read_json(folder / "strokes.json")["views"][v]]
                q = stroke_scores(strokes, cap, gray.shape[0])
                q["f1_tol1"] = stroke_scores(strokes, cap, gray.shape[0], tol=1.0)["f1"]
                f1s.append(q["f1"])
                by_cat.setdefault(folder.parent.name, []).append(q)
            ref, ms = timed(reference_strokes, strokes, gray.shape[0], settings[128])
            t_ref.append(ms)
            for k in range(args.variants):
                key = (0, "bench", folder.name, v, k)
                aug, ms = timed(augment_strokes, ref, rng_for(*key), settings[128])
                t_aug.append(ms)
                for size, st in settings.items():
                    out = [s * (size / REFERENCE_SIZE) for s in aug]
                    _, ms = timed(
                        draw_pencil, out, size, st.width_for(k) * size / REFERENCE_SIZE, rng_for(*key, "pencil"), st
                    )
                    t_ras[size].append(ms)
    med = statistics.median
    per_variant = med(t_vec) / args.variants + med(t_ref) / args.variants + med(t_aug) + med(t_ras[128])
    print(
        f"views: {len(views)} from {render_dir} (256² renders), variants/view: {args.variants}, repeats: {args.repeats}"
    )
    print(f"vectorize            {med(t_vec):7.2f} ms / view  (256² in)")
    print(f"resample to curves   {med(t_ref):7.2f} ms / view")
    print(f"augment strokes      {med(t_aug):7.2f} ms / variant")
    print(f"rasterize 128²       {med(t_ras[128]):7.2f} ms / variant")
    print(f"rasterize 512²       {med(t_ras[512]):7.2f} ms / variant (preview)")
    print(f"total per 128² variant (view work shared by {args.variants}): {per_variant:.2f} ms")
    if f1s:
        print(f"vectorization F1 vs captured strokes (2 px): median {med(f1s):.3f}, min {min(f1s):.3f}")
        print("category     views  meanF1(2px)  minF1(2px)  meanF1(1px)  minPrecision  median count ratio")
        for cat, qs in sorted(by_cat.items()):
            f = [q["f1"] for q in qs]
            print(
                f"{cat:12s} {len(qs):5d}  {np.mean(f):11.3f}  {min(f):10.3f}  "
                f"{np.mean([q['f1_tol1'] for q in qs]):11.3f}  {min(q['precision'] for q in qs):12.3f}  "
                f"{med([q['count_ratio'] for q in qs]):18.2f}"
            )
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
