"""Training throughput on a GPU: seconds per step at several batch sizes (batches held in memory,
so the figure is the model + loss alone), peak GPU memory, and the data loader's samples per
second with N workers (it must outpace the steps).

Usage: python bench/bench_train_gpu.py --dataset data/dataset --category airplane --template airplane
       [--batch-sizes 8 32] [--steps 30] [--workers 4] [--max-views 4]
Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch

from train.data import DataSettings, make_loader
from train.losses.total import weighted_sum
from train.losses.weights import template_weights
from train.model import SketchToPatches
from train.objective import Objective
from train.templates import load_template


def loader_rate(a, data: DataSettings, batch: int) -> float:
    """Samples per second the training loader delivers (after its workers have started)."""
    it = iter(make_loader(a.dataset, a.category, "train", data, 0, batch, a.workers, True))
    for _ in range(2):
        next(it)
    t0, n = time.perf_counter(), 0
    for _ in range(a.loader_batches):
        n += len(next(it)["images"])
    return n / (time.perf_counter() - t0)


def step_times(a, data: DataSettings, batch: int, dev: torch.device) -> dict:
    tpl = load_template(a.template)
    torch.manual_seed(0)
    model = SketchToPatches(tpl.initial_params()).to(dev)
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    obj = Objective(tpl, a.points)
    weights = template_weights(tpl.regularizers, {})
    it = iter(make_loader(a.dataset, a.category, "train", data, 0, batch, a.workers, True))
    batches = [next(it) for _ in range(4)]
    torch.cuda.reset_peak_memory_stats(dev) if dev.type == "cuda" else None
    times = []
    for step in range(a.steps + 3):
        b = batches[step % len(batches)]
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)
        t0 = time.perf_counter()
        params = model(b["images"].to(dev, non_blocking=True), b["view_mask"].to(dev))
        gen = torch.Generator().manual_seed(step)
        loss = weighted_sum(obj.batch_terms(params, b, obj.sample_st(gen), weights), weights).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)
        if step >= 3:  # warm-up: cuDNN autotuning, allocator growth
            times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    out = {
        "batch": batch,
        "median_s_per_step": round(med, 4),
        "steps_per_s": round(1 / med, 2),
        "samples_per_s_needed": round(batch / med, 1),
    }
    if dev.type == "cuda":
        out["peak_gpu_mem_mib"] = round(torch.cuda.max_memory_allocated(dev) / 2**20)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", default="data/dataset", help="dataset folder (default: the one `make dataset` builds)")
    ap.add_argument("--category", default="airplane")
    ap.add_argument("--template", default="airplane")
    ap.add_argument("--batch-sizes", type=int, nargs="+", default=[8, 32])
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--workers", type=int, default=4)
    ap.add_argument("--loader-batches", type=int, default=30)
    ap.add_argument("--max-views", type=int, default=4)
    ap.add_argument("--points", type=int, default=7000)
    ap.add_argument("--cpu", action="store_true", help="run on the CPU when there is no GPU (default: skip)")
    a = ap.parse_args()
    if not torch.cuda.is_available() and not a.cpu:
        print("bench_train_gpu: no CUDA device, skipped (--cpu runs it on the CPU)")
        return
    dev = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    data = DataSettings(max_views=a.max_views, n_points=a.points, image_size=128)
    res = {
        "device": torch.cuda.get_device_name(dev) if dev.type == "cuda" else "cpu",
        "torch": torch.__version__,
        "template": a.template,
        "max_views": a.max_views,
        "points": a.points,
        "workers": a.workers,
        "steps": [step_times(a, data, b, dev) for b in a.batch_sizes],
        "loader_samples_per_s": {str(b): round(loader_rate(a, data, b), 1) for b in a.batch_sizes},
    }
    print(json.dumps(res, indent=1), flush=True)


if __name__ == "__main__":
    main()
