"""How much of the frame each view's drawing fills, per category, and what the rig kept.

For every sketch of every split of a dataset: the ink's extent (the longer side of the box of its
ink pixels, as a share of the frame). Reported per category: views, the minimum, 5th percentile
and median extent, and the share of views under ``--floor`` (the representative rig's goal: none
under 0.35). With ``--work-dir``, also the share of the representative rig's candidate views that
pass its filter per category (recomputed from the prepared meshes the render records name).

Usage: .venv/bin/python bench/bench_views.py --dataset DS [--work-dir WORK] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import glob
import json
from pathlib import Path

import numpy as np
import webdataset as wds

from train.data import read_png, sketch_table
from train.sketch_input import INK_LEVEL


def ink_extent(img: np.ndarray) -> float:
    ink = (1.0 - img.astype(np.float32) / 255.0) > INK_LEVEL
    if not ink.any():
        return 0.0
    ys, xs = np.nonzero(ink)
    return float(max(xs.max() - xs.min() + 1, ys.max() - ys.min() + 1) / max(img.shape))


def sketch_extents(dataset: Path) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {}
    for shard in sorted(glob.glob(str(dataset / "*" / "*-[0-9][0-9][0-9][0-9][0-9].tar"))):
        category = Path(shard).parent.name
        for raw in wds.WebDataset(shard, shardshuffle=False):
            for names in sketch_table(raw).values():
                out.setdefault(category, []).extend(ink_extent(read_png(raw[n], 128)) for n in names)
    return out


def candidate_pass_share(work: Path) -> dict[str, float]:
    """Share of the representative rig's candidates that pass its filter, per category."""
    from render.rigs import seeded_views, silhouette_extent
    from render.settings import RenderSettings
    from render.worker import load_mesh

    s = RenderSettings()
    out: dict[str, list[float]] = {}
    for record in sorted(glob.glob(str(work / "render-*" / "*" / "*" / "record.json"))):
        rec = json.loads(Path(record).read_text())
        if rec.get("status", "ok") != "ok" or "mesh" not in rec:
            continue
        vertices, _ = load_mesh(Path(rec["mesh"]["path"]))
        pairs = seeded_views(s, rec["seed"], rec["category"], rec["model_id"], s.view_candidates)
        ext = [silhouette_extent(s, vertices, a, e) for a, e in pairs]
        floor = max(s.min_view_extent, s.view_extent_fraction * max(ext))
        out.setdefault(rec["category"], []).append(float(np.mean([e >= floor for e in ext])))
    return {c: float(np.mean(v)) for c, v in out.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--dataset", type=Path, default="data/dataset", help="dataset folder (default: the one `make dataset` builds)"
    )
    p.add_argument("--work-dir", type=Path, default=None)
    p.add_argument("--floor", type=float, default=0.35)
    p.add_argument("--json", type=Path, default=None)
    a = p.parse_args()
    ext = sketch_extents(a.dataset)
    kept = candidate_pass_share(a.work_dir) if a.work_dir else {}
    rows = {}
    print(f"{'category':10s} {'views':>6s} {'min':>6s} {'p5':>6s} {'median':>7s} {'<floor':>7s} {'kept':>6s}")
    for c, v in sorted(ext.items()):
        x = np.asarray(v)
        rows[c] = {
            "views": len(x),
            "min": float(x.min()),
            "p5": float(np.percentile(x, 5)),
            "median": float(np.median(x)),
            "under_floor": float((x < a.floor).mean()),
            **({"candidates_kept": kept[c]} if c in kept else {}),
        }
        r = rows[c]
        print(
            f"{c:10s} {r['views']:6d} {r['min']:6.3f} {r['p5']:6.3f} {r['median']:7.3f} {r['under_floor']:7.1%} "
            f"{r.get('candidates_kept', float('nan')):6.1%}"
        )
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
