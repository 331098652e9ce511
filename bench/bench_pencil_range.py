"""Pencil range of a dataset's sketches: ink darkness and ink cover, per category and variant.

Ink pixels are those darker than 0.1 (0 paper, 1 black) at 128²; "darkness" is their mean, "cover"
their share of the frame. The paper's seven released demo sketches measure darkness 0.23–0.31 and
cover 3–9 % this way; the goal is variants that span both those and dark thin line drawings.

Usage: .venv/bin/python bench/bench_pencil_range.py --dataset DS [--json OUT.json]
"""

from __future__ import annotations

import argparse
import glob
import json
from pathlib import Path

import numpy as np
import webdataset as wds

from train.data import read_png, sketch_table

INK = 0.1
PAPER_DEMOS = {"darkness": (0.23, 0.31), "cover": (0.03, 0.09)}


def ink_stats(img: np.ndarray) -> tuple[float, float]:
    d = 1.0 - img.astype(np.float32) / 255.0
    m = d > INK
    return (float(d[m].mean()) if m.any() else 0.0), float(m.mean())


def collect(dataset: Path) -> dict[tuple[str, int], np.ndarray]:
    out: dict[tuple[str, int], list] = {}
    for shard in sorted(glob.glob(str(dataset / "*" / "*-[0-9][0-9][0-9][0-9][0-9].tar"))):
        category = Path(shard).parent.name
        for raw in wds.WebDataset(shard, shardshuffle=False):
            for names in sketch_table(raw).values():
                for variant, name in enumerate(names):
                    out.setdefault((category, variant), []).append(ink_stats(read_png(raw[name], 128)))
    return {k: np.asarray(v) for k, v in out.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--dataset", type=Path, default="data/dataset", help="dataset folder (default: the one `make dataset` builds)"
    )
    p.add_argument("--json", type=Path, default=None)
    a = p.parse_args()
    rows = {}
    print(f"{'category':10s} {'variant':>7s} {'n':>5s} {'darkness p10/50/90':>22s} {'cover % p10/50/90':>20s}")
    for (c, k), v in sorted(collect(a.dataset).items()):
        dq, cq = np.percentile(v[:, 0], [10, 50, 90]), np.percentile(v[:, 1], [10, 50, 90])
        rows[f"{c}/{k}"] = {"n": len(v), "darkness": dq.round(3).tolist(), "cover": cq.round(4).tolist()}
        print(
            f"{c:10s} {k:7d} {len(v):5d} {dq[0]:6.3f} {dq[1]:6.3f} {dq[2]:6.3f}   "
            f"{100 * cq[0]:5.1f} {100 * cq[1]:5.1f} {100 * cq[2]:5.1f}"
        )
    print(f"paper's demo sketches: darkness {PAPER_DEMOS['darkness']}, cover {PAPER_DEMOS['cover']}")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
