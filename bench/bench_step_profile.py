"""Where a training step's time goes, and what the real step costs.

Each measured step runs twice on the same batch and samples, alternating:

* the real step, ``train.fit.train_step`` exactly as ``fit`` runs it (forward, every term of the
  template's loss through ``Objective.batch_terms``, backward, Adam) — the figure to quote;
* the same work split at part boundaries: encoder + head forward, patch evaluation (shared by
  the terms), point matching (shared by Chamfer and normal), each term's forward, the backward
  through the loss graph down to the network's output, the backward through the network, the
  optimizer step. The parts sum to about the real step (timer and split overhead aside).

Medians over steps of CPU seconds (process time: on a shared machine the figure a single-threaded
process would take alone), one process, ``--threads`` torch threads. Data loading is timed apart
(``fit`` loads in worker processes).

The network's outputs get noise of ``--noise`` (unit-sphere frame) added, so the collision term
sees the overlaps a model in training makes, not the crossing-free template.

Usage: OMP_NUM_THREADS=1 taskset -c 1 .venv/bin/python bench/bench_step_profile.py
       [--dataset DS --category airplane] [--template airplane] [--steps 10] [--batch-size 8]
       [--max-views 1] [--threads 1] [--image-size 128] [--encoder-width 64] [--json OUT]
       [--torch-profile TABLE.txt]
Without --dataset it writes fixture shards (boxes) to a temporary folder. ``--torch-profile``
runs one more real step (after the timed ones) under torch.profiler and writes its operator
table (``key_averages``, sorted by self CPU time) to the file given.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from fixtures_shards import write_fixture_shards  # noqa: E402

from train.data import DataSettings, make_loader  # noqa: E402
from train.fit import DivergenceGuard, clip_gradient, make_optimizer, train_step  # noqa: E402
from train.losses.terms import LOSS_TERMS, TermInputs  # noqa: E402
from train.losses.total import weighted_sum  # noqa: E402
from train.losses.weights import template_weights  # noqa: E402
from train.model import SketchToPatches  # noqa: E402
from train.objective import Objective  # noqa: E402
from train.templates import load_template  # noqa: E402


class _Noisy(torch.nn.Module):
    """The network with fixed-seed noise on its outputs (differentiable w.r.t. the network)."""

    def __init__(self, net: torch.nn.Module, noise: float, seed: int):
        super().__init__()
        self.net, self.noise, self.gen = net, noise, torch.Generator().manual_seed(seed)

    def forward(self, images, view_mask, pair_images=None):  # train_step's TrainingNet call
        params = self.net(images, view_mask)
        return {"params": params + self.noise * torch.randn(params.shape, generator=self.gen)}


def _split_step(net, optimizer, objective: Objective, batch: dict, st, weights, tick) -> None:
    """``train_step``'s work with a timer ``tick(part)`` between parts (same inputs, same result)."""
    params = net(batch["images"], batch["view_mask"])["params"]
    tick("encoder + head forward")
    dev = params.device
    on = objective.resident(dev)  # the template's constants, made once per device
    tn = None
    if weights.template_normal:
        from train.geometry.coons import evaluate_patches

        tn = evaluate_patches(on.template_patches, st).normals[0]
    mask = objective.patch_mask(batch["meta"], dev)
    sym = on.sym if on.sym.numel() else None
    patches, points = objective.template.patches_and_points(params)
    x = TermInputs(
        patches,
        st,
        batch["points"][..., :3],
        batch["points"][..., 3:],
        mask,
        tn,
        points if sym is not None else None,
        sym,
        objective.symmetry_valid(mask),
        objective.plane_x,
        on.pairs,
        objective.groups(batch, dev),
    )
    tick("loss inputs (masks, groups, template normals)")
    x.ev
    tick("patch evaluation (shared)")
    x.matches
    tick("matching: k-d trees (shared)")
    terms = {}
    for term in LOSS_TERMS:
        value = term.fn(x) if getattr(weights, term.name) else None
        terms[term.name] = params.new_zeros(params.shape[0]) if value is None else value
        tick(f"loss: {term.name} forward")
    loss = weighted_sum(terms, weights).mean()
    optimizer.zero_grad(set_to_none=True)
    (grad,) = torch.autograd.grad(loss, params)
    tick("backward: loss graph")
    params.backward(grad)
    tick("backward: encoder + head")
    clip_gradient(net, 0.0)
    tick("gradient norm (log.csv)")
    optimizer.step()
    tick("optimizer step (Adam)")


def profile(
    dataset: str,
    category: str,
    template: str,
    steps: int,
    batch: int,
    views: int,
    noise: float,
    image_size: int,
    width: int,
    torch_profile: str | None = None,
) -> dict[str, float]:
    tpl = load_template(template)
    weights = template_weights(tpl.regularizers)
    torch.manual_seed(0)
    model = SketchToPatches(tpl.initial_params(), **({} if width == 64 else {"encoder_width": width})).train()
    optimizer = make_optimizer(model, 1e-4, torch.device("cpu"))
    objective = Objective(tpl)
    data = DataSettings(max_views=views, image_size=image_size)
    loader = iter(make_loader(dataset, category, "train", data, 0, batch, 0, True))
    gen = torch.Generator().manual_seed(0)
    guard = DivergenceGuard(torch.device("cpu"))  # fit's non-finite check (kept on the device)
    times: dict[str, list[float]] = {}
    clock = [0.0]

    def tick(name: str) -> None:
        t = time.process_time()
        times.setdefault(name, []).append(t - clock[0])
        clock[0] = t

    for i in range(steps + 1):  # the first step warms up and is dropped
        clock[0] = time.process_time()
        b = next(loader)
        tick("data loading (fit: worker processes)")
        st = objective.sample_st(gen)
        seed = 1000 + i
        t0 = time.process_time()
        train_step(_Noisy(model, noise, seed), optimizer, objective, b, st, weights, torch.device("cpu"), guard=guard)
        times.setdefault("REAL STEP (train_step)", []).append(time.process_time() - t0)
        clock[0] = time.process_time()
        _split_step(_Noisy(model, noise, seed), optimizer, objective, b, st, weights, tick)
    if torch_profile:
        b = next(loader)
        _profile_one_step(Path(torch_profile), _Noisy(model, noise, 9999), optimizer, objective, b, weights, gen, guard)
    med = {k: statistics.median(v[1:]) for k, v in times.items()}
    parts = [k for k in med if not k.startswith(("REAL", "data"))]
    med["sum of the parts"] = sum(med[k] for k in parts)
    return med


def _profile_one_step(path: Path, net, optimizer, objective: Objective, batch: dict, weights, gen, guard) -> None:
    """One real step under torch.profiler (CPU activity): its operators by self CPU time to ``path``
    (the numba grid search of the matching runs outside torch: in the step's time, not the table's)."""
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profiler

    st = objective.sample_st(gen)
    with torch_profiler(activities=[ProfilerActivity.CPU]) as prof:
        train_step(net, optimizer, objective, batch, st, weights, torch.device("cpu"), guard=guard)
    table = prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=40)
    path.write_text(f"one train_step, torch.profiler, sorted by self CPU time\n{table}\n")


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
    ap.add_argument("--image-size", type=int, default=DataSettings.image_size)
    ap.add_argument("--encoder-width", type=int, default=64)
    ap.add_argument("--json", default=None, help="also write the medians here")
    ap.add_argument(
        "--torch-profile", default=None, metavar="PATH", help="write torch.profiler's table of one more step here"
    )
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    with tempfile.TemporaryDirectory() as tmp:
        ds, cat = a.dataset, a.category
        if ds is None:
            ds, cat = (
                str(write_fixture_shards(Path(tmp) / "ds", counts={"train": 16, "val": 2, "test": 2}, size=128)),
                "knife",
            )
        med = profile(
            ds,
            cat,
            a.template,
            a.steps,
            a.batch_size,
            a.max_views,
            a.noise,
            a.image_size,
            a.encoder_width,
            a.torch_profile,
        )
    head = (
        f"template={a.template} batch={a.batch_size} views<={a.max_views} threads={a.threads} noise={a.noise} "
        f"image={a.image_size} encoder_width={a.encoder_width} steps={a.steps}"
    )
    print(head)
    real = med["REAL STEP (train_step)"]
    print("| part | median CPU s/step | share of the real step |\n|---|---:|---:|")
    for k, v in med.items():
        print(f"| {k} | {v:.3f} | {100 * v / real:.0f} % |")
    if a.json:
        Path(a.json).write_text(json.dumps({"settings": vars(a), "median_cpu_s": med}, indent=1))


if __name__ == "__main__":
    main()
