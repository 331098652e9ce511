"""Where a training step's time goes: data loading, encoder forward+backward, each loss term
forward+backward. Medians over steps of CPU seconds (process time: on a shared machine the
figure a single-threaded process would take alone), one process, ``--threads`` torch threads.
Each term is timed on its own, so each includes evaluating the patches at the sample points.

The network outputs are the template plus noise of ``--noise`` (unit-sphere frame), so the
collision term sees the overlaps a model in training produces, not the crossing-free template.

Usage: OMP_NUM_THREADS=1 .venv/bin/python bench/bench_step_profile.py [--dataset DS --category airplane]
       [--template airplane] [--steps 10] [--batch-size 8] [--max-views 1] [--threads 1]
Without --dataset it writes fixture shards (boxes) to a temporary folder.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from fixtures_shards import write_fixture_shards  # noqa: E402

from train.data import DataSettings, make_loader  # noqa: E402
from train.losses.total import TERMS  # noqa: E402
from train.losses.weights import only_term, template_weights  # noqa: E402
from train.model import SketchToPatches  # noqa: E402
from train.objective import Objective  # noqa: E402
from train.templates import load_template  # noqa: E402


def profile(dataset: str, category: str, template: str, steps: int, batch: int, views: int, noise: float) -> dict[str, float]:
    tpl = load_template(template)
    weights = template_weights(tpl.regularizers)
    model = SketchToPatches(tpl.initial_params()).train()
    objective = Objective(tpl)
    loader = iter(make_loader(dataset, category, "train", DataSettings(max_views=views), 0, batch, 0, True))
    gen = torch.Generator().manual_seed(0)
    times: dict[str, list[float]] = {}

    def tick(name: str, t0: float) -> float:
        t1 = time.process_time()
        times.setdefault(name, []).append(t1 - t0)
        return t1

    for _ in range(steps + 1):  # the first step warms up and is dropped
        t = time.process_time()
        b = next(loader)
        t = tick("data loading", t)
        params = model(b["images"], b["view_mask"])
        jitter = noise * torch.randn(params.shape, generator=gen)
        t = tick("encoder + head forward", t)
        out = (params.detach() + jitter).requires_grad_(True)
        st = objective.sample_st(gen)
        grad = torch.zeros_like(out)
        for name in TERMS:
            if not getattr(weights, name):
                continue
            terms = objective.batch_terms(out, b, st, only_term(name, weights))
            (g,) = torch.autograd.grad(getattr(weights, name) * terms[name].mean(), out, allow_unused=True)
            grad += 0 if g is None else g
            t = tick(f"loss: {name} (fwd+bwd)", t)
        params.backward(grad)
        tick("encoder + head backward", t)
    med = {k: statistics.median(v[1:]) for k, v in times.items()}
    med["total"] = sum(med.values())
    return med


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", default=None)
    ap.add_argument("--category", default="knife")
    ap.add_argument("--template", default="airplane")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--batch-size", type=int, default=8)
    ap.add_argument("--max-views", type=int, default=1)
    ap.add_argument("--noise", type=float, default=0.02)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    with tempfile.TemporaryDirectory() as tmp:
        ds, cat = a.dataset, a.category
        if ds is None:
            ds, cat = str(write_fixture_shards(Path(tmp) / "ds", counts={"train": 16, "val": 2, "test": 2}, size=128)), "knife"
        med = profile(ds, cat, a.template, a.steps, a.batch_size, a.max_views, a.noise)
    print(f"template={a.template} batch={a.batch_size} views<={a.max_views} threads={a.threads} noise={a.noise}")
    print("| part | median CPU s/step | share |\n|---|---:|---:|")
    for k, v in med.items():
        print(f"| {k} | {v:.3f} | {100 * v / med['total']:.0f} % |")


if __name__ == "__main__":
    main()
