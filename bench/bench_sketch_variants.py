"""How far person-like variants of test sketches move a trained knife network's prediction,
read through predict's normalization and through the old path (grey + resize): issue 32's table.

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_sketch_variants.py                 # builds + trains (~10 min)
    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_sketch_variants.py --checkpoint RUN/best.pt --dataset DS

Without ``--checkpoint`` it builds the small knife dataset and trains the cheap knife run of
tests/test_sketch_variants.py under ``--work`` (reused when there). Prints a Markdown table: the
mean control-point distance between the predictions for two different test models, and per
variant the distance between its prediction and its clean sketch's, before and after.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from sketch_variants import CATEGORY, cheap_knife_run, measure, split_sketches, table  # noqa: E402

from train.fit import load_run  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--checkpoint", help="a knife run's best.pt (default: train the cheap run under --work)")
    p.add_argument("--dataset", help="dataset folder whose test split gives the sketches (with --checkpoint)")
    p.add_argument("--work", default="work/bench-sketch-variants", help="dataset and run of the default")
    p.add_argument("--models", type=int, default=12, help="test models whose sketches are varied")
    p.add_argument("--json", help="also write the figures here")
    a = p.parse_args()
    if a.checkpoint:
        if not a.dataset:
            p.error("--checkpoint needs --dataset (its test sketches)")
        ckpt, dataset = Path(a.checkpoint), Path(a.dataset)
    else:
        ckpt, dataset = cheap_knife_run(Path(a.work))
    run = load_run(ckpt)
    sketches = split_sketches(dataset, run.settings.category or CATEGORY, a.models)
    m = measure(run, sketches, Path(a.work) / "variants")
    print(f"checkpoint {ckpt} (step {run.step}), {len(sketches)} test models of {dataset}")
    print(table(m))
    if a.json:
        Path(a.json).write_text(json.dumps(m, indent=1))


if __name__ == "__main__":
    main()
