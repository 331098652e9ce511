"""Training: sketches -> template parameters, the paper's loss, Adam, checkpoints with resume.

Run directory layout::

    <out>/config.json       settings of the run (a resume must match them)
    <out>/checkpoint.pt     model + optimizer + step (rank 0, atomic); with ``--ema``, "model" is
                            the weight average and "train_model" the weights training continues
    <out>/best.pt           the checkpoint with the lowest validation Chamfer so far (``val_every``)
    <out>/log.csv           step, total and per-term losses, validation Chamfer, seconds
    <out>/tb/               TensorBoard scalars
    <out>/loss.png          loss curves
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import math
import pickle
import re
import time
from pathlib import Path
from typing import Any

import torch
from torch.nn.parallel import DistributedDataParallel

from pipeline.core.atomic import atomic_path, dumps_json, write_bytes
from pipeline.core.seeding import derive_seed
from pipeline.core.settings_io import SettingError, flag_name, from_dict, setting
from train.augmentation import Jitter
from train.data import DataSettings, make_loader, param_mirror, shard_framing, shard_urls
from train.distributed import DistInfo, from_main, mean_over_ranks, setup, teardown
from train.errors import UsageError, one_line
from train.losses.contrast import info_nce
from train.losses.total import TERMS, weighted_sum
from train.losses.weights import LossWeights, only_term
from train.model import SketchToPatches, TrainingNet
from train.objective import Objective
from train.precision import PRECISIONS, network_autocast, place_network
from train.resnet import last_stage_cells
from train.sketch_input import Framing
from train.templates import Template, TemplateError, load_template
from train.weight_average import WeightAverage

CSV_FIELDS = ("step", "loss") + TERMS + ("contrast", "fit_readout", "val_chamfer", "lr", "grad_norm", "seconds")
LR_SCHEDULES = ("constant", "cosine")


@dataclasses.dataclass(frozen=True)
class FitSettings:
    """One training run; ``python -m train fit`` has a flag for each field but ``weights``."""

    dataset: str = setting(help="dataset folder holding <category>/<split>-NNNNN.tar")
    category: str = setting(help="the category inside --dataset to train on")
    template: str = setting(help="sphere24, sphere54, a category name, or a template file")
    out: str = setting(help="run folder (re-using it resumes the run)")
    steps: int = setting(1000, "optimizer steps in all (a resumed run continues to this count)")
    batch_size: int = setting(8, "samples per step (per rank under torchrun)")
    lr: float = setting(1e-4, "Adam's learning rate (the peak one under --lr-schedule cosine)")
    output_lr_scale: float = setting(
        1.0,
        "the output layer learns at --lr times this (the encoder and hidden layers at --lr): each "
        "output sums 256 features, so one Adam step moves a control point ~256x as far as it moves "
        "a weight, and thin plates (the airplane's wings) cross at a rate the encoder needs",
    )
    lr_schedule: str = setting(
        "constant",
        "constant, or cosine: linear warm-up over --warmup-steps, then a cosine "
        "decay to 0 at --steps (the schedule follows --steps, so resume with the same --steps)",
    )
    warmup_steps: int = setting(0, "steps of linear warm-up under --lr-schedule cosine (unused when constant)")
    seed: int = setting(0, "seeds the network's initial weights, the data order and the augmentation")
    workers: int = setting(2, "data loader worker processes per rank")
    max_views: int = setting(DataSettings.max_views, "training draws 1..max_views views per sample")
    n_points: int = setting(DataSettings.n_points, "target / patch sample points per shape", flag="points")
    image_size: int = setting(DataSettings.image_size, "sketches are resized to this square size")
    encoder_width: int = setting(
        64,
        "channels of the encoder's first stage, x1/2/4/8 in its four stages (64: "
        "ResNet-18 as in the paper; 32: about a third of its CPU time)",
    )
    input_blur: float = setting(
        0.0,
        "feed the encoder two more channels, the drawing blurred at this sigma and 3x it (px at "
        "--image-size; 0: the drawing alone, as in the paper)",
    )
    page_coordinates: bool = setting(
        False,
        "feed the encoder two more channels, x and y across the page (CoordConv; not in the paper): "
        "where on the page the ink lies, handed to the first convolution",
    )
    pool_grid: int = setting(
        1,
        "average the encoder's last stage over this many cells a side and keep them apart (1: one "
        "global average, as in ResNet-18; 2: a 2x2 layout, 4x the code's features; at most the last stage's "
        "cells, 4 at --image-size 128: nothing pooled; not in the paper)",
    )
    min_crop: float = setting(
        Jitter.min_crop,
        "training jitter: each drawing is cropped to a random square of this fraction of its side or "
        "more and resized back (a scale change of up to 1/min_crop); 1: drawn at the scale it was rendered",
    )
    checkpoint_every: int = setting(500, "write RUN_DIR/checkpoint.pt every N steps (and at the end)")
    log_every: int = setting(10, "a row of RUN_DIR/log.csv every N steps")
    val_every: int = setting(0, "validation Chamfer every N steps; keeps RUN_DIR/best.pt (0: off)")
    device: str | None = setting(None, "default: cuda when present, else cpu")
    precision: str = setting(
        "fp32",
        "fp32, or bf16: on a GPU the network runs in bfloat16 autocast with channels-last "
        "convolutions (the loss stays fp32; BENCHMARKS.md compares the two); a CPU run is fp32",
    )
    match_normals: float | None = setting(
        None,
        "normal-aware matching in training: pair points by (xyz, λ·normal), λ = this "
        "(0: nearest point; default: the template file's, 0.1 for the thin-walled bathtub and mug, "
        "docs/train.md)",
    )
    contrast: float = setting(
        0.0,
        "weight of the contrastive term on the encoder's codes (two drawings of one model "
        "encode alike; not in the paper; 0: off)",
    )
    pair_loss: float = setting(
        0.0,
        "weight of the paper's loss on the second drawing of each sample (the one the contrastive "
        "term reads), so each step teaches both drawings of its models (not in the paper; 0: off)",
    )
    clip_grad: float = setting(
        0.0,
        "clip the gradient's global norm to this before each update (0: off; "
        "log.csv's grad_norm column shows the norms a run sees)",
    )
    ema: float = setting(
        0.0,
        "keep an exponential moving average of the weights with this decay (e.g. 0.999) and "
        "validate, keep and hand out the average instead of the training weights (0: off)",
    )
    shape_basis: int = setting(
        0,
        "fit the template to this many training models before training and let the output layer "
        "move it along the fits' principal directions (train/shape_basis.py; 0: one output per "
        "parameter, as in the paper)",
    )
    basis_directions: int = setting(
        128,
        "with --shape-basis: at most this many principal directions (those holding 99 %% of the "
        "fits' variance, if fewer); fewer directions are a stronger prior and fewer outputs to learn",
    )
    fit_anneal_steps: int = setting(
        0,
        "the fit term's weight falls linearly from --w-fit to 0 over this many steps, then stays 0 "
        "(0: constant --w-fit; the term needs a --fit-patches dataset)",
    )
    fit_readout: float = setting(
        0.0,
        "weight of the fit stage's targets taught to the encoder through a training-only linear "
        "readout of its codes, never through the output layer (not in the paper; 0: off; needs a "
        "--fit-patches dataset)",
    )
    init_encoder: str = setting(
        "",
        "a checkpoint (any category's, same --encoder-width) whose encoder and hidden layers start "
        "this run; the output layer starts at the template as always (not in the paper; '': fresh weights)",
    )
    weights: LossWeights = LossWeights()

    def __post_init__(self) -> None:
        # checked here, not in the CLI, so library callers are refused alike (a run of 0 steps
        # used to "finish" with a NaN loss; 0 points or pixels failed deep inside torch or OpenCV)
        for name in (
            "steps",
            "batch_size",
            "max_views",
            "n_points",
            "image_size",
            "encoder_width",
            "checkpoint_every",
            "log_every",
            "basis_directions",
            "pool_grid",
        ):
            _require(self, name, _is_int(getattr(self, name)) and getattr(self, name) >= 1, "an integer >= 1")
        # a grid finer than the last stage's map would only copy its cells: more features, nothing new
        cells = last_stage_cells(self.image_size)
        _require(self, "pool_grid", self.pool_grid <= cells, f"at most {cells} at --image-size {self.image_size}")
        for name in ("warmup_steps", "workers", "val_every", "fit_anneal_steps", "shape_basis"):
            _require(self, name, _is_int(getattr(self, name)) and getattr(self, name) >= 0, "an integer >= 0")
        _require(self, "lr", _is_number(self.lr) and 0 < self.lr < math.inf, "a learning rate > 0")
        _require(
            self,
            "output_lr_scale",
            _is_number(self.output_lr_scale) and 0 < self.output_lr_scale < math.inf,
            "a factor > 0",
        )
        _require(self, "precision", self.precision in PRECISIONS, f"one of {', '.join(PRECISIONS)}")
        _require(self, "lr_schedule", self.lr_schedule in LR_SCHEDULES, f"one of {', '.join(LR_SCHEDULES)}")
        _require(
            self,
            "ema",
            _is_number(self.ema) and (self.ema == 0 or 0 < self.ema < 1),
            "0 (off) or a decay between 0 and 1",
        )
        _require(self, "min_crop", _is_number(self.min_crop) and 0 < self.min_crop <= 1, "a fraction in (0, 1]")
        for name in ("clip_grad", "contrast", "pair_loss", "match_normals", "input_blur", "fit_readout"):
            value = getattr(self, name)
            if name == "match_normals" and value is None:  # the template file's, resolved by fit
                continue
            _require(self, name, _is_number(value) and 0 <= value < math.inf, "0 (off) or a positive number")

    def identity(self) -> dict:
        """Settings that define the run: a resume must match them (steps and logging may change)."""
        d = dataclasses.asdict(self)
        for k in ("steps", "checkpoint_every", "log_every", "val_every", "device", "workers", "out", "precision"):
            d.pop(k)
        return d


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _require(settings: Any, name: str, ok: bool, expected: str) -> None:
    """SettingError naming the field and its command-line flag unless ``ok``."""
    if not ok:
        field = {f.name: f for f in dataclasses.fields(settings)}[name]
        flag = "--" + flag_name(field).replace("_", "-")
        value = getattr(settings, name)
        raise SettingError(f"{name} must be {expected}, got {value!r} ({flag})", type(settings).__name__, name)


def save_checkpoint(
    path: Path,
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    step: int,
    settings: FitSettings,
    template: Template,
    val_chamfer: float | None = None,
    train_model: torch.nn.Module | None = None,
    framing: Framing | None = None,
    readout: torch.nn.Module | None = None,
) -> None:
    """``model`` is the network the checkpoint hands out (evaluate, predict); ``train_model``, when
    it differs (a weight average is handed out), holds the weights a resume continues training;
    ``framing``, how the training sketches fill their frame (a person's drawing is re-framed so);
    ``readout``, the training-only readout of ``--fit-readout`` (kept for a resume only)."""
    with atomic_path(path) as tmp:
        torch.save(
            {
                "step": step,
                "val_chamfer": val_chamfer,
                "model": model.state_dict(),
                **({"train_model": train_model.state_dict()} if train_model is not None else {}),
                "optimizer": optimizer.state_dict(),
                "settings": dataclasses.asdict(settings),
                "template": settings.template,
                # the template itself: a rebuilt shipped template must not change what an old run means
                "template_json": template.to_json(),
                "num_params": model.num_params,
                **({"framing": dataclasses.asdict(framing)} if framing is not None else {}),
                **({"fit_readout": readout.state_dict()} if readout is not None else {}),
            },
            tmp,
        )


# What every checkpoint save_checkpoint writes holds; a file without them is not one of ours.
CHECKPOINT_KEYS = ("settings", "model", "step")


def load_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> dict[str, Any]:
    """A checkpoint's dict, read without running any code: ``weights_only`` unpickling accepts
    tensors and plain data only, so a crafted file cannot execute commands. UsageError (naming
    the file) for a missing, empty, unreadable, foreign or code-carrying file."""
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"{path}: no such checkpoint file" + (" (it is a folder)" if path.is_dir() else ""))
    if path.stat().st_size == 0:
        raise UsageError(f"{path}: the checkpoint file is empty")
    try:
        ckpt = torch.load(path, map_location=device, weights_only=True)
    except pickle.UnpicklingError as exc:
        # torch names the class or function the pickle would have called: "GLOBAL posix.system"
        named = re.search(r"GLOBAL (\S+)", str(exc))
        if named is None:  # garbage, not a pickle asking for code
            raise UsageError(f"{path}: not a readable checkpoint (a bad pickle)") from None
        raise UsageError(
            f"{path}: refused: it holds Python objects other than tensors and plain data "
            f"({named.group(1)}; weights_only load); only load checkpoints you trust "
            "(docs/train.md)"
        ) from None
    except Exception as exc:  # noqa: BLE001 - truncated or not a torch file: the unpickler fails any which way
        first = one_line(exc).split(". ")[0][:200]  # torch's own advice after it is about weights_only=False
        raise UsageError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {first})") from None
    missing = [k for k in CHECKPOINT_KEYS if not isinstance(ckpt, dict) or k not in ckpt]
    if missing:
        raise UsageError(f"{path}: not a sketch2patch checkpoint: missing {missing[0]!r}")
    if not isinstance(ckpt["settings"], dict):
        raise UsageError(f"{path}: not a sketch2patch checkpoint: 'settings' is not a dict")
    return ckpt


def template_from_checkpoint(ckpt: dict) -> Template:
    """The template the run trained with: the copy in the checkpoint, or (checkpoints from
    before it was stored) the template named in its settings."""
    if ckpt.get("template_json"):
        return Template.from_json(ckpt["template_json"])
    return load_template(ckpt["settings"]["template"])


def saved_basis(ckpt: dict) -> torch.Tensor | None:
    """The output layer's shape basis a checkpoint's network reads out in (None: a plain layer)."""
    basis = ckpt["model"].get("out.basis") if isinstance(ckpt.get("model"), dict) else None
    return basis if isinstance(basis, torch.Tensor) else None


def _new_basis(settings: FitSettings, template: Template, info: DistInfo, out: Path) -> torch.Tensor | None:
    """A fresh run's shape basis (``--shape-basis N``), its summary written to ``out/shape_basis.json``.
    Under DDP only rank 0 fits (~0.8 CPU s a model) and the others receive its basis."""
    if not settings.shape_basis:
        return None
    if not info.is_main:
        return from_main(None, info)
    from train.shape_basis import shape_basis

    basis = shape_basis(
        settings.dataset,
        settings.category,
        template,
        settings.shape_basis,
        settings.seed,
        max_directions=settings.basis_directions,
    )
    summary = {
        "shapes": basis.shapes,
        "directions": int(basis.directions.shape[0]),
        "explained": round(basis.explained, 4),
        "cpu_s": basis.cpu_s,
    }
    out.mkdir(parents=True, exist_ok=True)
    write_bytes(out / "shape_basis.json", dumps_json(summary).encode())
    return from_main(torch.from_numpy(basis.directions), info)


@dataclasses.dataclass(frozen=True)
class TrainedRun:
    """A checkpoint ready to use: the network (eval mode), the template it trained with, its
    settings and the step it was saved at."""

    model: SketchToPatches
    template: Template
    settings: FitSettings
    step: int
    framing: Framing = Framing()  # checkpoints from before it was stored: the shipped default


# Settings removed since, with the value that meant "off": a checkpoint saved with that value
# loads as if it never had the setting; any other value still fails, naming it.
# encoder_lr: a separate encoder learning rate; contrast_queue: earlier drawings' codes as extra
# negatives of the contrastive term; momentum_queue: the same from a momentum encoder; norm: the
# network's normalization layers (all tried and removed, docs/experiments.md)
_REMOVED_SETTINGS = {"encoder_lr": None, "contrast_queue": 0, "momentum_queue": 0, "norm": "batch"}


def checkpoint_settings(ckpt: dict) -> FitSettings:
    """The settings a checkpoint was trained with (older checkpoints: new fields keep defaults)."""
    saved = {k: v for k, v in ckpt["settings"].items() if not (k in _REMOVED_SETTINGS and v == _REMOVED_SETTINGS[k])}
    return from_dict(FitSettings, saved)


def _saved_settings(path: str | Path, ckpt: dict) -> FitSettings:
    """checkpoint_settings, its SettingError naming the file."""
    try:
        return checkpoint_settings(ckpt)
    except SettingError as exc:
        raise SettingError(f"{path}: {exc}", exc.owner, exc.field) from None


def _saved_template(path: str | Path, ckpt: dict) -> Template:
    """template_from_checkpoint, a template that does not load naming the file."""
    try:
        return template_from_checkpoint(ckpt)
    except (TemplateError, KeyError, TypeError) as exc:
        raise UsageError(f"{path}: its template does not load ({one_line(exc)})") from None


def build_network(settings: FitSettings, template: Template, basis: torch.Tensor | None = None) -> SketchToPatches:
    """The network a run's settings describe, at the template (untrained): what ``fit`` trains and
    ``load_run`` loads weights into."""
    return SketchToPatches(
        template.initial_params(),
        encoder_width=settings.encoder_width,
        basis=basis,
        input_blur=settings.input_blur,
        page_coordinates=settings.page_coordinates,
        pool_grid=settings.pool_grid,
    )


def load_run(path: str | Path) -> TrainedRun:
    """The run saved at ``path`` (``checkpoint.pt`` or ``best.pt``), on the CPU."""
    ckpt = load_checkpoint(path)
    settings = _saved_settings(path, ckpt)
    template = _saved_template(path, ckpt)
    model = build_network(settings, template, saved_basis(ckpt))
    try:
        model.load_state_dict(ckpt["model"])
    except (RuntimeError, TypeError, AttributeError) as exc:  # torch lists every mismatch, one a line
        raise UsageError(
            f"{path}: its weights do not fit the network its settings describe ({one_line(exc)[:300]})"
        ) from None
    return TrainedRun(model.eval(), template, settings, int(ckpt["step"]), _saved_framing(path, ckpt))


def _saved_framing(path: str | Path, ckpt: dict) -> Framing:
    try:
        return Framing(**ckpt["framing"]) if isinstance(ckpt.get("framing"), dict) else Framing()
    except (TypeError, ValueError) as exc:
        raise UsageError(f"{path}: its sketch framing does not load ({one_line(exc)})") from None


@torch.no_grad()
def validation_chamfer(model: SketchToPatches, loader, objective: Objective, device: torch.device) -> float:
    """Mean L_Ch over a split (one view, fixed sample grid): the number model selection uses."""
    was_training = model.training
    model.eval()
    count = 0
    weights = only_term("chamfer")
    st = objective.sample_st(None)
    total = torch.zeros((), dtype=torch.float64, device=device)  # summed on the device: one read at the end
    for batch in loader:
        params = model(batch["images"].to(device, non_blocking=True), batch["view_mask"])  # mask read on the host
        terms = objective.batch_terms(params, batch, st, weights, training=False)
        total = total + terms["chamfer"].sum().double()
        count += params.shape[0]
    model.train(was_training)
    return float(total) / max(count, 1)


def _best_so_far(out: Path, start: int) -> float:
    """Validation Chamfer of best.pt when resuming a run (inf when there is none yet)."""
    path = out / "best.pt"
    if not start or not path.exists():
        return float("inf")
    value = load_checkpoint(path).get("val_chamfer")
    return float("inf") if value is None else float(value)


def _read_log(path: Path, upto: int) -> list[dict]:
    if not path.exists():
        return []
    with open(path) as f:
        return [row for row in csv.DictReader(f) if int(row["step"]) <= upto]


def learning_rate(settings: FitSettings, step: int) -> float:
    """The learning rate of step ``step`` (0-based): a pure function of the step, so a resumed run
    continues the schedule where it stopped."""
    if settings.lr_schedule == "constant":
        return settings.lr
    if step < settings.warmup_steps:
        return settings.lr * (step + 1) / settings.warmup_steps
    span = max(settings.steps - settings.warmup_steps, 1)
    done = min(step - settings.warmup_steps, span) / span
    return settings.lr * 0.5 * (1.0 + math.cos(math.pi * done))


def step_weights(settings: FitSettings, step: int) -> LossWeights:
    """The loss weights of step ``step`` (0-based): the fit term's falls linearly from its weight
    at step 0 to 0 at ``fit_anneal_steps`` (a pure function of the step, so a resume continues it)."""
    n = settings.fit_anneal_steps
    if not n or not settings.weights.fit:
        return settings.weights
    return dataclasses.replace(settings.weights, fit=settings.weights.fit * max(0.0, 1.0 - step / n))


def make_optimizer(
    model: torch.nn.Module,
    lr: float,
    device: torch.device,
    output_lr_scale: float = 1.0,
    output: torch.nn.Module | None = None,
) -> torch.optim.Optimizer:
    """Adam; the fused kernel on CPU and CUDA (same update, one pass over the parameters: about 7x
    cheaper than the per-tensor loop on one CPU core, BENCHMARKS.md). With ``output_lr_scale`` != 1
    the parameters of ``output`` (the output layer, one of ``model``'s modules) form a second group
    whose ``lr_scale`` the schedule multiplies in (``set_learning_rate``)."""
    fused = torch.device(device).type in ("cpu", "cuda")
    if output_lr_scale == 1.0:  # one group, as every run before the option
        return torch.optim.Adam(model.parameters(), lr=lr, fused=fused)
    if output is None:
        raise ValueError("output_lr_scale needs the output layer (output=)")
    own = {id(p) for p in output.parameters()}
    groups = [
        {"params": [p for p in model.parameters() if id(p) not in own], "lr_scale": 1.0},
        {"params": [p for p in model.parameters() if id(p) in own], "lr_scale": output_lr_scale},
    ]
    if len(groups[1]["params"]) != len(own):
        raise ValueError("output must be one of the model's modules")
    return torch.optim.Adam(groups, lr=lr, fused=fused)


def set_learning_rate(optimizer: torch.optim.Optimizer, lr: float) -> None:
    """Every group at ``lr`` times its ``lr_scale`` (1 when it has none)."""
    for group in optimizer.param_groups:
        group["lr"] = lr * group.get("lr_scale", 1.0)


def clip_gradient(net: torch.nn.Module, limit: float) -> torch.Tensor:
    """The gradient's global norm; with ``limit`` > 0 a larger gradient is scaled down to it
    (no scaling pass when off: the norm is only measured, for log.csv)."""
    grads = [p.grad for p in net.parameters() if p.grad is not None]
    norm = torch.nn.utils.get_total_norm(grads).detach()
    if limit > 0:
        torch.nn.utils.clip_grads_with_norm_(net.parameters(), limit, norm)
    return norm


class Diverged(FloatingPointError):
    """A step's loss or gradient norm was not finite; ``step`` is that step (1-based)."""

    def __init__(self, step: int, loss: float, grad_norm: float):
        super().__init__(_not_finite(loss, grad_norm))
        self.step = step


def _not_finite(loss: float, grad_norm: float) -> str:
    return f"the loss is {loss:g} and the gradient norm {grad_norm:g}"


class DivergenceGuard:
    """``train_step``'s non-finite check without a read-back per step.

    The check stays on the device: a step whose loss or gradient norm is not finite sets a flag
    there, and the fused Adam update reads that flag there (``found_inf``, as for a gradient
    scaler) and leaves weights and moments untouched, that step and every later one, so the
    weights stay the last finite ones. ``check`` reads the flag, once, where the run reads values
    back anyway (a log row, validation, a checkpoint) and raises :class:`Diverged` naming the
    first bad step, its loss and gradient norm. Steps are counted from ``first_step`` (the
    0-based step the run starts at)."""

    def __init__(self, device: torch.device, first_step: int = 0):
        self.steps = first_step  # steps seen so far (a host counter: no read-back)
        self.bad = torch.zeros((), dtype=torch.bool, device=device)  # a step so far was not finite
        self.first = torch.zeros((), dtype=torch.long, device=device)  # the first such step, 1-based
        self.loss = torch.zeros((), device=device)  # its loss and gradient norm, for the message
        self.grad_norm = torch.zeros((), device=device)

    @staticmethod
    def supports(optimizer: torch.optim.Optimizer) -> bool:
        """Whether ``optimizer`` can skip its update on the device (the fused Adam of
        ``make_optimizer`` on CPU and CUDA); with another, ``train_step`` checks on the host."""
        return bool(getattr(optimizer, "_step_supports_amp_scaling", False)) and bool(optimizer.defaults.get("fused"))

    def update(self, optimizer: torch.optim.Optimizer, finite: torch.Tensor, loss: torch.Tensor, norm: torch.Tensor):
        """Record one step's verdict ``finite`` and take the update unless a step so far failed."""
        self.steps += 1
        new = ~finite & ~self.bad
        self.first = torch.where(new, self.steps, self.first)
        self.loss = torch.where(new, loss.detach().float(), self.loss)
        self.grad_norm = torch.where(new, norm.detach().float(), self.grad_norm)
        self.bad = self.bad | ~finite
        optimizer.found_inf = self.bad.float()  # 1: the fused kernel returns before touching anything
        optimizer.step()

    def check(self) -> None:
        """Raise :class:`Diverged` if a step so far was not finite (one read-back)."""
        if bool(self.bad):
            raise Diverged(int(self.first), float(self.loss), float(self.grad_norm))


def train_step(
    net: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    objective: Objective,
    batch: dict,
    st: torch.Tensor,
    weights: LossWeights,
    device: torch.device,
    contrast: float = 0.0,
    clip_grad: float = 0.0,
    guard: DivergenceGuard | None = None,
    precision: str = "fp32",
    fit_readout: float = 0.0,
    pair_loss: float = 0.0,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """One optimisation step of a :class:`TrainingNet` (or its DDP wrapper) on a loader batch at
    samples ``st``: forward, the loss, backward, update. Returns the batch loss and the per-item
    terms (``bench/bench_step_profile.py`` times this); with ``contrast`` > 0 the batch must hold
    ``pair_images`` and the terms include "contrast". The terms also hold "grad_norm", the
    gradient's global norm before clipping; with ``clip_grad`` > 0 a larger one is scaled down to
    it (under DDP the gradients are already averaged over ranks here, so every rank clips alike).
    A loss or gradient that is not finite raises FloatingPointError before the update, so the
    weights stay the last finite ones (the averaged gradient's norm is the same on every rank,
    so under DDP all ranks stop at the same step). With a ``guard`` (``fit``'s, when the optimizer
    supports it) the step reads nothing back from the device: the guard skips the update on the
    device instead and ``guard.check()`` raises later, naming the step.

    Host round trips: none on a GPU but the collision term's culling (``train.losses.collision``);
    the loss and terms come back as device tensors (``fit`` reads them every ``--log-every``).
    ``precision`` "bf16" runs the network (not the loss) in bfloat16 autocast on a GPU.
    ``fit_readout`` > 0 adds the readout's fit term (a net with a readout, a fitted batch) as
    "fit_readout". ``pair_loss`` > 0 (a batch with ``pair_images``) adds the terms of the pair's
    drawings at that weight."""
    # host-to-device copies do not wait for the device (non_blocking; the loader pins its batches
    # on a GPU run), and the view mask stays on the host: the encoder reads it there
    pair = batch["pair_images"].to(device, non_blocking=True) if contrast > 0 or pair_loss > 0 else None
    with network_autocast(device, precision):
        out = net(batch["images"].to(device, non_blocking=True), batch["view_mask"], pair, pair_loss > 0)
    out = {k: v.float() for k, v in out.items()}  # the loss's geometry stays fp32
    terms = objective.batch_terms(out["params"], batch, st, weights)
    loss = weighted_sum(terms, weights).mean()
    if pair_loss > 0:  # the same targets and samples: the pair shows the same (mirrored alike) model
        loss = (
            loss
            + pair_loss * weighted_sum(objective.batch_terms(out["pair_params"], batch, st, weights), weights).mean()
        )
    if contrast > 0:
        terms["contrast"] = info_nce(out["codes"], out["pair_codes"])
        loss = loss + contrast * terms["contrast"].mean()
    if fit_readout > 0:
        readout = objective.readout_term(out["readout"], batch)
        terms["fit_readout"] = readout if readout is not None else out["readout"].new_zeros(len(out["readout"]))
        loss = loss + fit_readout * terms["fit_readout"].mean()
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    terms["grad_norm"] = clip_gradient(net, clip_grad)
    finite = torch.isfinite(loss.detach()) & torch.isfinite(terms["grad_norm"])
    if guard is not None and guard.supports(optimizer):
        guard.update(optimizer, finite, loss, terms["grad_norm"])
        return loss, terms
    if not bool(finite):  # without a guard: one scalar read per step
        raise FloatingPointError(_not_finite(float(loss.detach()), float(terms["grad_norm"])))
    optimizer.step()
    return loss, terms


def with_template_defaults(settings: FitSettings) -> FitSettings:
    """``settings`` with what it leaves to the template file filled in (the matching λ), so the
    run's recorded settings say what it trained with."""
    if settings.match_normals is not None:
        return settings
    return dataclasses.replace(settings, match_normals=load_template(settings.template).match_normals)


def fit(settings: FitSettings, progress: bool = True) -> dict:
    """Train (or resume) a run; returns {"step", "last_loss", "out"}. Works under torchrun."""
    settings = with_template_defaults(settings)
    info = setup(settings.device)
    try:
        result = _fit(settings, info, progress)
    except BaseException:
        # no closing barrier: a rank that failed alone (say, on a bad shard only it reads) must
        # exit, so that torchrun stops the others, instead of waiting for them forever
        teardown(info, wait=False)
        raise
    teardown(info)
    return result


def _start_body_from(model: SketchToPatches, path: str) -> None:
    """Copy the encoder and hidden layers of the network in checkpoint ``path`` into ``model``:
    a sketch encoder already trained on another category. UsageError naming the file when its
    body does not fit (another encoder width or input)."""
    saved = load_checkpoint(path)["model"]
    if not isinstance(saved, dict):
        raise UsageError(f"{path}: not a sketch2patch checkpoint: its 'model' holds no network weights")
    own = model.state_dict()
    body = {k: v for k, v in saved.items() if k.startswith(("encoder.", "hidden.", "fields."))}
    wrong = [k for k, v in body.items() if k not in own or own[k].shape != v.shape]
    missing = [k for k in own if k.startswith(("encoder.", "hidden.")) and k not in body]
    if wrong or missing:
        what = f"{wrong[0]!r} does not fit" if wrong else f"it has no {missing[0]!r}"
        raise UsageError(
            f"{path}: its network cannot start this one ({what}; same --encoder-width, --input-blur, "
            "--page-coordinates and --pool-grid?)"
        )
    model.load_state_dict(body, strict=False)


def training_data(settings: FitSettings, template: Template) -> DataSettings:
    """What the training stream draws for ``settings``: its views, points, image size, jitter, and
    a second drawing of each model when a term needs one; drawings are mirrored at random only
    where the template declares a mirror plane."""
    return DataSettings(
        max_views=settings.max_views,
        n_points=settings.n_points,
        image_size=settings.image_size,
        pair=settings.contrast > 0 or settings.pair_loss > 0,
        jitter=Jitter(min_crop=settings.min_crop, flip=template.symmetry is not None),
    )


def _fit(settings: FitSettings, info: DistInfo, progress: bool) -> dict:
    out = Path(settings.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: not a folder (--out)")
    ckpt_path, start = out / "checkpoint.pt", 0
    ckpt = load_checkpoint(ckpt_path, info.device) if ckpt_path.exists() else None
    if ckpt is not None:
        check_resume(ckpt_path, _saved_settings(ckpt_path, ckpt), settings)
    # a resumed run keeps the template it started with, even if the named one was rebuilt since
    template = load_template(settings.template) if ckpt is None else _saved_template(ckpt_path, ckpt)
    # how the training sketches fill the frame, kept with the run for predict's normalization
    framing = (
        _saved_framing(ckpt_path, ckpt)
        if ckpt is not None and "framing" in ckpt
        else shard_framing(settings.dataset, settings.category, settings.image_size)
    )
    basis = saved_basis(ckpt) if ckpt is not None else _new_basis(settings, template, info, out)
    torch.manual_seed(settings.seed)  # same initial weights on every rank
    model = build_network(settings, template, basis)
    if ckpt is None and settings.init_encoder:
        _start_body_from(model, settings.init_encoder)
    model = place_network(model, info.device, settings.precision)
    trainee = TrainingNet(model, template.initial_params() if settings.fit_readout > 0 else None)
    optimizer = make_optimizer(trainee, settings.lr, info.device, settings.output_lr_scale, model.out)
    if ckpt is not None:
        model.load_state_dict(ckpt.get("train_model", ckpt["model"]))
        if trainee.readout is not None:
            if "fit_readout" not in ckpt:
                raise UsageError(f"{ckpt_path}: saved without the --fit-readout readout; resume it without the option")
            trainee.readout.load_state_dict(ckpt["fit_readout"])
        optimizer.load_state_dict(ckpt["optimizer"])
        start = int(ckpt["step"])
    best = _best_so_far(out, start)  # read before anything is written: a bad best.pt stops the run here
    average = WeightAverage(model, settings.ema) if settings.ema > 0 else None
    if average is not None and ckpt is not None:
        average.model.load_state_dict(ckpt["model"])
    served = average.model if average is not None else model  # what validation sees and checkpoints hand out
    trained = model if average is not None else None
    net: torch.nn.Module = DistributedDataParallel(trainee) if info.enabled else trainee
    objective = Objective(template, settings.n_points, match_normals=settings.match_normals)
    data = training_data(settings, template)
    # A resumed run draws a fresh, still seeded data order keyed by the step it resumes from.
    loader = make_loader(
        settings.dataset,
        settings.category,
        "train",
        data,
        derive_seed(settings.seed, "data", start),
        settings.batch_size,
        settings.workers,
        True,
        info.rank,
        info.world,
        template.symmetry is not None,
        param_mirror(template) if settings.weights.fit or settings.fit_readout else None,
        pin_memory=info.device.type == "cuda",
    )
    logger = _Logger(out, start, info, settings) if info.is_main else None
    val_loader = None
    if settings.val_every:
        shard_urls(settings.dataset, settings.category, "val")  # checked on every rank: all stop alike
    if settings.val_every and info.is_main:
        val_data = DataSettings(eval_views=1, n_points=settings.n_points, image_size=settings.image_size)
        val_loader = make_loader(
            settings.dataset, settings.category, "val", val_data, 0, settings.batch_size, train=False
        )
    bar = None
    if progress and info.is_main and start < settings.steps:
        from tqdm import tqdm

        bar = tqdm(total=settings.steps, initial=start, desc="fit", dynamic_ncols=True)
    stream = iter(loader)
    needs_fits = bool(settings.weights.fit or settings.fit_readout)
    first = next(stream) if needs_fits and start < settings.steps else None
    if first is not None and "fit_params" not in first:
        flag = "--w-fit" if settings.weights.fit else "--fit-readout"
        raise UsageError(
            f"{settings.dataset}: {flag} needs fitted patches, and the {settings.category} shards have none "
            f"(build the dataset with --fit-patches, or give {flag} 0)"
        )
    net.train()
    last = None  # null in the result when no step runs (a resume already at --steps)
    kept = start if ckpt is not None else None  # the step checkpoint.pt holds
    guard = DivergenceGuard(info.device, start)  # the non-finite check, read where the loop reads anyway
    t0 = time.perf_counter()
    for step in range(start, settings.steps):
        batch, first = (first, None) if first is not None else (next(stream), None)
        gen = torch.Generator().manual_seed(derive_seed(settings.seed, "st", step) % (2**63))
        lr = learning_rate(settings, step)
        set_learning_rate(optimizer, lr)
        done = step + 1
        # the same on every rank, unlike ``val`` (rank 0 only): the logging branch below holds
        # collectives, and a rank entering it alone would wait for the others forever
        val_step = settings.val_every > 0 and (done % settings.val_every == 0 or done == settings.steps)
        log_step = done % settings.log_every == 0 or done == settings.steps or val_step
        keep_step = done % settings.checkpoint_every == 0 or done == settings.steps
        try:
            loss, terms = train_step(
                net,
                optimizer,
                objective,
                batch,
                objective.sample_st(gen),
                step_weights(settings, step),
                info.device,
                settings.contrast,
                settings.clip_grad,
                guard,
                settings.precision,
                settings.fit_readout,
                settings.pair_loss,
            )
            if log_step or keep_step:  # before anything is read, validated or saved (every rank alike)
                guard.check()
        except FloatingPointError as exc:
            raise UsageError(_diverged(getattr(exc, "step", done), exc, ckpt_path, kept)) from None
        if average is not None:
            average.update(step)
        val = None
        if val_loader is not None and val_step:
            val = validation_chamfer(served, val_loader, objective, info.device)
            if val < best:
                best = val
                save_checkpoint(
                    out / "best.pt",
                    served,
                    optimizer,
                    done,
                    settings,
                    template,
                    val_chamfer=val,
                    train_model=trained,
                    framing=framing,
                )
        if log_step:
            last, row = _log_values(loss, terms, info)
            if logger:
                logger.log(
                    done, last, {**row, "val_chamfer": "" if val is None else val, "lr": lr}, time.perf_counter() - t0
                )
        if keep_step:
            if logger:
                save_checkpoint(
                    ckpt_path,
                    served,
                    optimizer,
                    done,
                    settings,
                    template,
                    train_model=trained,
                    framing=framing,
                    readout=trainee.readout,
                )
            kept = done
        if bar:
            bar.update(1)
            if log_step:  # the loss shown is the last logged one: no read-back on the other steps
                bar.set_postfix(loss=f"{last:.4f}")
    if bar:
        bar.close()
    if logger:
        logger.close()
    return {
        "step": max(start, settings.steps),
        "last_loss": last,
        "out": str(out),
        "param_digest": param_digest(served),
    }


def _log_values(loss: torch.Tensor, terms: dict[str, torch.Tensor], info: DistInfo) -> tuple[float, dict[str, float]]:
    """The loss and each term's batch mean as numbers (averaged over ranks): one stacked tensor,
    one collective and one read-back for the whole row."""
    means = torch.stack([loss.detach().float(), *(v.mean().detach().float() for v in terms.values())])
    values = mean_over_ranks(means, info).tolist()
    return values[0], dict(zip(terms, values[1:]))


def _diverged(step: int, exc: FloatingPointError, ckpt_path: Path, kept: int | None) -> str:
    """Why training stopped at a non-finite loss, and what is left on disk."""
    left = "no checkpoint was saved" if kept is None else f"{ckpt_path} keeps step {kept}"
    return f"step {step}: training diverged ({exc}); stopped before the update, {left}; try a lower --lr or --clip-grad"


def settings_differences(saved: FitSettings, now: FitSettings) -> list[str]:
    """``name saved -> now`` for each run-defining setting that differs (nested: ``weights.flat``)."""

    def flat(d: dict, prefix: str = "") -> dict:
        out = {}
        for k, v in d.items():
            out.update(flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k: v})
        return out

    a, b = flat(saved.identity()), flat(now.identity())
    return [f"{k} {a.get(k)!r} -> {b.get(k)!r}" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]


def check_resume(ckpt_path: Path, saved: FitSettings, now: FitSettings) -> None:
    """UsageError naming every setting a resume changes (``--steps`` and logging may change)."""
    diff = settings_differences(saved, now)
    if diff:
        raise UsageError(
            f"{ckpt_path}: the run there has different settings ({'; '.join(diff)}); "
            "resume with the same settings or use another --out"
        )


def param_digest(model: torch.nn.Module) -> str:
    """Hash of the trainable parameters: equal on every rank when DDP keeps them in sync.

    (BatchNorm running statistics are per-rank between DDP's buffer broadcasts; rank 0's are saved.)
    """
    h = hashlib.sha256()
    for name, t in sorted(model.named_parameters()):
        h.update(name.encode())
        h.update(t.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()[:16]


class _Logger:
    """CSV + TensorBoard + loss plot, rank 0 only. A resume drops log rows past the checkpoint."""

    def __init__(self, out: Path, start: int, info: DistInfo, settings: FitSettings):
        from torch.utils.tensorboard import SummaryWriter

        out.mkdir(parents=True, exist_ok=True)
        cfg = {**dataclasses.asdict(settings), "world_size": info.world}
        write_bytes(out / "config.json", dumps_json(cfg).encode())
        self.csv_path = out / "log.csv"
        rows = _read_log(self.csv_path, start)
        with atomic_path(self.csv_path) as tmp, open(tmp, "w", newline="") as f:
            w = csv.DictWriter(f, CSV_FIELDS)
            w.writeheader()
            w.writerows(rows)
        self.file = open(self.csv_path, "a", newline="")
        self.writer = csv.DictWriter(self.file, CSV_FIELDS)
        self.tb = SummaryWriter(str(out / "tb"), purge_step=start + 1 if start else None)
        self.out = out

    def log(self, step: int, loss: float, terms: dict[str, float | str], seconds: float) -> None:
        self.writer.writerow({"step": step, "loss": loss, **terms, "seconds": round(seconds, 3)})
        self.file.flush()
        self.tb.add_scalar("loss/total", loss, step)
        for k, v in terms.items():
            if v != "":  # validation runs only every val_every steps
                group = "val" if k.startswith("val_") else "opt" if k == "lr" else "loss"
                self.tb.add_scalar(f"{group}/{k}", v, step)

    def close(self) -> None:
        from train.plots import plot_losses

        self.file.close()
        self.tb.close()
        plot_losses(self.csv_path, self.out / "loss.png")


def read_config(run_dir: str | Path) -> dict:
    return json.loads((Path(run_dir) / "config.json").read_text())
