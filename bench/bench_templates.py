"""Time template construction (cuboids → lattice → merge → Template) and its checks per category."""

from __future__ import annotations

import statistics
import time

import torch

from pipeline.core.normalize import unit_sphere_transform
from pipeline.shapes import CATEGORIES, generate
from train.templates.authoring.checks import closed_manifold_problems, self_intersections
from train.templates.authoring.from_cuboids import normalize_boxes, template_from_boxes
from train.templates.authoring.part_boxes import category_boxes


def main(repeats: int = 3) -> None:
    torch.set_num_threads(1)
    for cat in CATEGORIES:
        m = generate(cat, 0, 0, defect_fraction=0.0)
        v, _ = m.merged()
        boxes = normalize_boxes(category_boxes(cat, m.cuboids), *unit_sphere_transform(v))
        build, check = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            tpl = template_from_boxes(boxes, cat)
            t1 = time.perf_counter()
            assert not closed_manifold_problems(tpl) and not self_intersections(tpl)
            build.append(t1 - t0)
            check.append(time.perf_counter() - t1)
        print(
            f"{cat:9s} {len(m.cuboids):3d} cuboids -> {tpl.num_patches:4d} patches  "
            f"build median {statistics.median(build) * 1e3:7.1f} ms  checks median {statistics.median(check) * 1e3:7.1f} ms"
        )


if __name__ == "__main__":
    main()
