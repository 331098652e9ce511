"""Training throughput on a GPU: the real training step (``train.fit.train_step``, a recipe's
loss, fused Adam) timed per variant and batch size with batches held in memory (so the figure is
the model + loss alone), a per-part breakdown, peak GPU memory, the loss of each variant against
fp32 on one fixed batch, a torch.profiler table, and the data loader's samples per second.

Variants (the A/B runs in one process, alternated per batch size):
  fp32-cdist  the nearest-point search as before: chunked torch.cdist + argmin (main before the
              fused kernel)
  fp32        the fused nearest-point kernel (``train.nn_search.fused_nearest``)
  bf16        fused kernel + the network in bf16 autocast, channels-last (``--precision bf16``)

Usage: python bench/bench_train_gpu.py --dataset DATASET --category airplane --recipe airplane
       [--encoder-width 64] [--batch-sizes 32 256] [--variants fp32-cdist fp32 bf16] [--steps 10] [--workers 8 15]
       [--profile OUT.txt] [--json OUT.json]
Prints one JSON object.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import time

import torch

import train.nn_search as nn_search
from train.data import DataSettings, make_loader
from train.fit import DivergenceGuard, make_optimizer, train_step, with_template_defaults
from train.model import SketchToPatches, TrainingNet
from train.objective import Objective
from train.precision import network_autocast, place_network
from train.recipes import recipe
from train.templates import load_template

VARIANTS = {"fp32-cdist": ("fp32", False), "fp32": ("fp32", True), "bf16": ("bf16", True)}


def search_kernel(fused: bool) -> contextlib.AbstractContextManager:
    """The GPU nearest-point search as a variant asks: the fused kernel, or main's cdist before it."""
    return nn_search.forced_search("fused" if fused else "cdist")


class Setup:
    """A recipe's network, optimizer, objective and weights on ``dev`` (seeded: equal per variant)."""

    def __init__(self, a, precision: str, dev: torch.device):
        s = with_template_defaults(recipe(a.recipe, a.dataset, "unused"))
        self.settings = s
        tpl = load_template(s.template)
        torch.manual_seed(0)
        model = SketchToPatches(tpl.initial_params(), encoder_width=a.encoder_width or s.encoder_width)
        # a head that moves the patches (an untrained one predicts the template for any input,
        # so precision could not show in the loss): outputs about 0.02 from the template
        torch.nn.init.normal_(model.out.weight, std=2e-3)
        self.model = place_network(model, dev, precision)
        self.net = TrainingNet(self.model)
        self.optimizer = make_optimizer(self.net, s.lr, dev, s.output_lr_scale, self.model.out)
        self.objective = Objective(tpl, a.points, match_normals=s.match_normals)
        self.weights = s.weights
        self.precision, self.dev = precision, dev


def data_settings(a, s) -> DataSettings:
    return DataSettings(max_views=a.max_views, n_points=a.points, image_size=128, pair=s.contrast > 0)


def batches(a, s, batch: int) -> list[dict]:
    it = iter(
        make_loader(a.dataset, a.category, "train", data_settings(a, s), 0, batch, a.workers[0], True, pin_memory=True)
    )
    return [next(it) for _ in range(3)]


def sync(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def step_times(a, su: Setup, held: list[dict], fused: bool) -> dict:
    dev, s = su.dev, su.settings
    guard = DivergenceGuard(dev)
    times = []
    torch.cuda.reset_peak_memory_stats(dev) if dev.type == "cuda" else None
    with search_kernel(fused):
        for step in range(a.steps + 3):
            b = held[step % len(held)]
            st = su.objective.sample_st(torch.Generator().manual_seed(step))
            sync(dev)
            t0 = time.perf_counter()
            train_step(
                su.net, su.optimizer, su.objective, b, st, su.weights, dev, s.contrast, s.clip_grad, guard, su.precision
            )
            sync(dev)
            if step >= 3:  # warm-up: cuDNN autotuning, allocator growth, kernel compilation
                times.append(time.perf_counter() - t0)
    guard.check()
    med = statistics.median(times)
    out = {"median_s_per_step": round(med, 4), "samples_per_s": round(len(held[0]["images"]) / med, 1)}
    if dev.type == "cuda":
        out["peak_gpu_mem_mib"] = round(torch.cuda.max_memory_allocated(dev) / 2**20)
    return out


def breakdown(su: Setup, b: dict, fused: bool, repeats: int = 5) -> dict:
    """Seconds per part of one step (each part synchronized on its own): network forward, the
    loss inputs and each term's forward, backward, optimizer. Medians of ``repeats``."""
    from train.losses.terms import LOSS_TERMS, TermInputs

    dev, s, obj = su.dev, su.settings, su.objective
    parts: dict[str, list[float]] = {}

    def timed(name, fn):
        sync(dev)
        t0 = time.perf_counter()
        r = fn()
        sync(dev)
        parts.setdefault(name, []).append(time.perf_counter() - t0)
        return r

    with search_kernel(fused):
        for r in range(repeats + 1):
            st = obj.sample_st(torch.Generator().manual_seed(r)).to(dev)
            pair = b["pair_images"].to(dev) if s.contrast > 0 else None

            def forward():
                with network_autocast(dev, su.precision):
                    return su.net(b["images"].to(dev), b["view_mask"], pair)

            out = timed("network forward", forward)
            params = out["params"].float()
            mask = obj.patch_mask(b["meta"], dev)
            groups = obj.groups(b, dev)
            patches, ctrl = timed("template decode", lambda: obj.template.patches_and_points(params))
            on = obj.resident(dev)
            x = TermInputs(
                patches,
                st,
                b["points"][..., :3].to(dev),
                b["points"][..., 3:].to(dev),
                mask,
                None,
                ctrl,
                on.sym if obj.sym.numel() else None,
                obj.symmetry_valid(mask),
                obj.plane_x,
                on.pairs,
                groups,
                obj.match_normals,
            )
            timed("patch samples", lambda: x.ev)
            timed("matching", lambda: x.matches)
            total = 0
            for term in LOSS_TERMS:
                w = getattr(su.weights, term.name)
                if w:
                    v = timed(f"term {term.name}", lambda: term.fn(x))
                    if v is not None:
                        total = total + w * v.mean()
            su.optimizer.zero_grad(set_to_none=True)
            timed("backward", lambda: total.backward())
            timed("optimizer", lambda: su.optimizer.step())
    return {k: round(statistics.median(v[1:]), 4) for k, v in parts.items()}


def terms_on(su: Setup, b: dict, fused: bool) -> tuple[dict, torch.Tensor]:
    """Each loss term's batch mean and the gradient of the total w.r.t. the network outputs, for
    one fixed batch and samples (network in eval mode: no batch statistics move)."""
    dev, obj = su.dev, su.objective
    su.net.eval()
    with search_kernel(fused):
        with network_autocast(dev, su.precision):
            params = su.net(b["images"].to(dev), b["view_mask"])["params"]
        params = params.float().detach().requires_grad_(True)
        st = obj.sample_st(None)
        terms = obj.batch_terms(params, b, st, su.weights)
        total = sum(getattr(su.weights, k) * v for k, v in terms.items() if getattr(su.weights, k, 0)).mean()
        (grad,) = torch.autograd.grad(total, params)
    su.net.train()
    return {k: float(v.mean()) for k, v in terms.items() if getattr(su.weights, k, 0)}, grad


def fidelity(a, dev: torch.device, b: dict) -> dict:
    """Loss terms and output gradient of each variant against fp32-cdist on the same weights and
    batch: relative differences and the gradient's cosine similarity."""
    ref_terms, ref_grad = terms_on(Setup(a, "fp32", dev), b, False)
    out = {"fp32-cdist terms": {k: round(v, 6) for k, v in ref_terms.items()}}
    for name in a.variants:
        precision, fused = VARIANTS[name]
        if name == "fp32-cdist":
            continue
        t, g = terms_on(Setup(a, precision, dev), b, fused)
        out[name] = {
            "max_relative_term_difference": round(
                max(abs(t[k] - ref_terms[k]) / max(abs(ref_terms[k]), 1e-12) for k in ref_terms), 6
            ),
            "relative_differences": {k: round(abs(t[k] - ref_terms[k]) / max(abs(ref_terms[k]), 1e-12), 6) for k in t},
            "output_gradient_cosine": round(
                float(torch.nn.functional.cosine_similarity(g.flatten(), ref_grad.flatten(), 0)), 6
            ),
        }
    with torch.no_grad():  # the two searches' answers on the network's patch samples
        su = Setup(a, "fp32", dev)
        params = su.net(b["images"].to(dev), b["view_mask"])["params"]
        pts = su.objective.template.patches_from_params(params)
        from train.geometry.coons import evaluate_patches

        q = evaluate_patches(pts, su.objective.sample_st(None)).points.flatten(1, 2)
        ref = b["points"][..., :3].to(dev)
        i_fused, i_cdist = nn_search.fused_nearest(q, ref), nn_search.device_nearest(q, ref)
        d = lambda i: ((q - nn_search.gather_points(ref, i)) ** 2).sum(-1)  # noqa: E731
        out["search_same_index_share"] = round(float((i_fused == i_cdist).float().mean()), 6)
        out["search_fused_never_farther"] = bool((d(i_fused) <= d(i_cdist) + 1e-7).all())
    return out


def profile(a, su: Setup, held: list[dict], path: str) -> None:
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    dev, s = su.dev, su.settings
    guard = DivergenceGuard(dev)
    st = su.objective.sample_st(torch.Generator().manual_seed(0))
    train_step(
        su.net, su.optimizer, su.objective, held[0], st, su.weights, dev, s.contrast, s.clip_grad, guard, su.precision
    )
    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if dev.type == "cuda" else [])
    with torch_profile(activities=acts) as prof:
        for i in range(3):
            train_step(
                su.net,
                su.optimizer,
                su.objective,
                held[i % len(held)],
                st,
                su.weights,
                dev,
                s.contrast,
                s.clip_grad,
                guard,
                su.precision,
            )
        sync(dev)
    table = prof.key_averages()
    with open(path, "w") as f:
        for key in ("self_cuda_time_total", "self_device_time_total", "self_cpu_time_total"):
            try:
                f.write(f"three train_steps, batch {len(held[0]['images'])}, {su.precision}, sorted by {key}\n")
                f.write(table.table(sort_by=key, row_limit=40) + "\n\n")
            except Exception as exc:  # noqa: BLE001 - key names differ between torch versions
                f.write(f"({key}: {exc})\n")


def loader_rate(a, s, batch: int, workers: int) -> float:
    """Samples per second the training loader delivers (after its workers have started)."""
    it = iter(
        make_loader(a.dataset, a.category, "train", data_settings(a, s), 0, batch, workers, True, pin_memory=True)
    )
    for _ in range(2):
        next(it)
    t0, n = time.perf_counter(), 0
    while time.perf_counter() - t0 < a.loader_seconds:
        n += len(next(it)["images"])
    return n / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", default="data/dataset", help="dataset folder (default: the one `make dataset` builds)")
    ap.add_argument("--category", default="airplane")
    ap.add_argument("--recipe", default="airplane", help="the training recipe whose loss and network are timed")
    ap.add_argument("--batch-sizes", type=int, nargs="+", default=[32, 256])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--workers", type=int, nargs="+", default=[8], help="loader workers (the rate is taken for each)")
    ap.add_argument("--loader-seconds", type=float, default=15.0)
    ap.add_argument("--max-views", type=int, default=4)
    ap.add_argument("--points", type=int, default=7000)
    ap.add_argument(
        "--encoder-width", type=int, default=64, help="64: ResNet-18 itself, the paper's; 0: the recipe's (32)"
    )
    ap.add_argument("--breakdown", action="store_true", help="also time each part of the step")
    ap.add_argument("--profile", help="write a torch.profiler table of the last variant at the largest batch here")
    ap.add_argument("--json", help="also write the result here")
    ap.add_argument("--cpu", action="store_true", help="run on the CPU when there is no GPU (default: skip)")
    a = ap.parse_args()
    if not torch.cuda.is_available() and not a.cpu:
        print("bench_train_gpu: no CUDA device, skipped (--cpu runs it on the CPU)")
        return
    dev = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    s = recipe(a.recipe, a.dataset, "unused")
    res: dict = {
        "device": torch.cuda.get_device_name(dev) if dev.type == "cuda" else "cpu",
        "torch": torch.__version__,
        "recipe": a.recipe,
        "max_views": a.max_views,
        "points": a.points,
        "encoder_width": a.encoder_width or s.encoder_width,
        "steps": {},
    }
    held = {b: batches(a, s, b) for b in a.batch_sizes}
    for b in a.batch_sizes:
        for name in a.variants:
            precision, fused = VARIANTS[name]
            su = Setup(a, precision, dev)
            res["steps"].setdefault(str(b), {})[name] = step_times(a, su, held[b], fused)
            if a.breakdown:
                res["steps"][str(b)][name]["parts_s"] = breakdown(su, held[b][0], fused)
            print(json.dumps({str(b): {name: res["steps"][str(b)][name]}}), flush=True)
    res["fidelity"] = fidelity(a, dev, held[a.batch_sizes[0]][0])
    print(json.dumps({"fidelity": res["fidelity"]}), flush=True)
    if a.profile:
        precision, _ = VARIANTS[a.variants[-1]]
        profile(a, Setup(a, precision, dev), held[max(a.batch_sizes)], a.profile)
    b = max(a.batch_sizes)
    res["loader_samples_per_s"] = {f"batch {b}, {w} workers": round(loader_rate(a, s, b, w), 1) for w in a.workers}
    text = json.dumps(res, indent=1)
    print(text, flush=True)
    if a.json:
        with open(a.json, "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
