"""Evaluation on a split: the paper's ablation-table metrics plus peers' Chamfer and F-score,
for the trained network and two baselines every model must beat: the template alone, and the
sketch-blind mean shape (the mean of the network's outputs over the train split, used as one
constant prediction for every sketch; what the network gives without looking at the sketch).

Metrics (means over samples):
  chamfer          the paper's L_Ch: unsquared distances, Jacobian-weighted on the patch side
  normal, flat, template_normal, collision   the paper's loss terms of the same names
  intersecting_pairs   number of patch pairs whose triangulations cross (exact test)
  chamfer_sq_x1000 peers' Chamfer (AtlasNet / Pixel2Mesh): squared distances, the two directed
                   means summed, ×1000, between area-uniform samples of the patches and the target
  normal_consistency   mean |cos| between nearest-neighbour normals, both directions
  fscore@τ         F-score at distance τ on the unit-sphere frame, one per requested τ
  cad_clean        (network, ``cad_check`` > 0) share of the first ``cad_check`` predictions whose
                   exported solid the CAD kernel finds free of self-interference: the verdict
                   ``predict`` prints (``train.export.kernel_check``), averaged
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import torch

from pipeline.core.atomic import write_json
from pipeline.core.schema import SPLITS
from pipeline.core.settings_io import setting
from train.augmentation import SteadyAverage
from train.data import ALL_SPLITS, DataSettings, make_loader, splits_with_shards
from train.errors import UsageError
from train.export.bicubic import coons_to_bezier
from train.export.kernel_check import KernelVerdict, kernel_verdict
from train.export.units import CadUnits
from train.fit import load_run
from train.geometry.intersections import count_intersecting_pairs
from train.geometry.sampling import sample_surface_uniform
from train.losses.weights import LossWeights
from train.metrics import chamfer_l2_x1000, fscore, normal_consistency, relative_change_interval
from train.mirror_average import mirror_averaged
from train.objective import Objective

LOSS_METRICS = ("chamfer", "normal", "flat", "template_normal", "collision")
PEER_METRICS = ("chamfer_sq_x1000", "normal_consistency")


def metric_names(taus: tuple[float, ...]) -> tuple[str, ...]:
    return LOSS_METRICS + ("intersecting_pairs",) + PEER_METRICS + tuple(f"fscore@{t:g}" for t in taus)


def batch_metrics(
    objective: Objective, params: torch.Tensor, batch: dict, taus: tuple[float, ...], generator: torch.Generator
) -> dict[str, torch.Tensor]:
    """Every metric per batch item ``(B,)`` for network outputs ``params (B, D)``."""
    points = batch["points"].to(params.device)
    target, target_n = points[..., :3], points[..., 3:]
    mask = objective.patch_mask(batch["meta"], params.device)
    weights = LossWeights(symmetry=0.0)
    terms = objective.batch_terms(params, batch, objective.sample_st(None), weights, training=False)
    out = {k: terms[k] for k in LOSS_METRICS}
    patches = objective.template.patches_from_params(params)
    # peers' metrics on area-uniform samples of the present patches, as many as the target has
    samples = [
        sample_surface_uniform(p if mask is None else p[mask[b]], target.shape[1], generator)
        for b, p in enumerate(patches)
    ]
    pp = torch.stack([x for x, _ in samples]).to(target.dtype)
    pn = torch.stack([n for _, n in samples]).to(target.dtype)
    out["chamfer_sq_x1000"] = chamfer_l2_x1000(pp, target)
    out["normal_consistency"] = normal_consistency(pp, pn, target, target_n)
    for t in taus:
        out[f"fscore@{t:g}"] = fscore(pp, target, t)
    out["intersecting_pairs"] = torch.tensor(
        [
            float(count_intersecting_pairs(p, objective.pairs, None if mask is None else mask[b]))
            for b, p in enumerate(patches)
        ]
    )
    return out


def cad_verdicts(objective: Objective, params: torch.Tensor, meta: list[dict]) -> list[KernelVerdict]:
    """The CAD kernel's verdict on each prediction, on its present patches (its patch indices
    count those), at the CAD export's scale (as ``predict`` sews and checks them)."""
    mask = objective.patch_mask(meta, params.device)
    patches = objective.template.patches_from_params(params.double())
    mm = CadUnits().mm
    return [
        kernel_verdict(coons_to_bezier((p if mask is None else p[mask[b]]).numpy()) * mm) for b, p in enumerate(patches)
    ]


@torch.no_grad()
def mean_output(model, loader) -> torch.Tensor:
    """Mean network output ``(D,)`` over a loader's samples: the sketch-blind constant prediction."""
    total, count = None, 0
    for batch in loader:
        params = model(batch["images"], batch["view_mask"]).double().sum(0)
        total = params if total is None else total + params
        count += len(batch["key"])
    if not count:
        raise ValueError("no samples to average for the sketch-blind baseline")
    return (total / count).float()


def blind_output(model, dataset: str | Path, category: str, data: DataSettings, batch_size: int = 8) -> torch.Tensor:
    """The sketch-blind baseline ``(D,)``: the mean network output over the category's train split."""
    return mean_output(model, make_loader(dataset, category, "train", data, 0, batch_size, train=False))


@dataclasses.dataclass(frozen=True)
class EvaluateSettings:
    """``python -m train evaluate``: one flag per field."""

    checkpoint: str = setting(help="checkpoint.pt or best.pt of a run")
    dataset: str | None = setting(None, "dataset folder holding <category>/<split>-NNNNN.tar (or --images)")
    images: str | None = setting(
        None,
        "instead of a dataset: a folder of drawings (PNG, JPEG, WebP, TIFF), each normalized as predict does, "
        "with the CAD kernel's verdict on each; DIR/<stem>.obj|.ply|.stl beside a drawing is its ground truth, "
        "measured with the metrics below",
    )
    split: str = setting("test", f"split to evaluate: {', '.join(SPLITS)}, or all (every split the dataset has)")
    category: str | None = setting(None, "category (default: the run's)")
    blind_from: str | None = setting(
        None,
        "dataset whose train split gives the sketch-blind mean (default: --dataset); for meshes the run "
        "never saw (a folder of real meshes) give the run's own training dataset",
    )
    leave_out: tuple[str, ...] = setting(
        (),
        "patch labels to measure as absent in every prediction, for targets known to lack those parts "
        "(TORCS car bodies have no wheels: --leave-out wheel_front wheel_rear)",
    )
    views: int = setting(1, "views per sample the network sees")
    variant: int = setting(
        0, "pencil variant of each view (0: the dark, thin line drawing; 1: the light, broad, shaded one)"
    )
    tau: tuple[float, ...] = setting((0.02, 0.05), "F-score distance thresholds (unit-sphere frame)")
    points: int | None = setting(
        None,
        "sample points per shape for the metrics (default: the run's --points); Chamfer falls as samples "
        "get denser, so compare runs trained at different --points at one count",
    )
    limit: int | None = setting(None, "evaluate at most this many samples (default: all)")
    out: str | None = setting(None, "JSON path (default: eval_<checkpoint>_<split>.json next to the checkpoint)")
    mirror_average: bool = setting(
        False,
        "answer each drawing with the mean of the network's reading of it and of its left-right flip, "
        "mirrored back (symmetric templates; twice the inference cost; the blind mean alike)",
    )
    steady: bool = setting(
        False,
        "answer each drawing as predict does: the mean over 27 small jitters of it (27 times the inference "
        "cost; the blind mean alike; --images always does)",
    )
    cad_check: int = setting(
        16,
        "check this many predictions with the CAD kernel (cad_clean: the share predict would call clean; "
        "a second or more each; 0: off)",
    )

    def __post_init__(self) -> None:
        # the split is the command line's to check; the numbers evaluate() checks for every caller
        if self.split not in SPLITS + (ALL_SPLITS,):
            raise UsageError(f"split must be one of {', '.join(SPLITS + (ALL_SPLITS,))}, got {self.split!r} (--split)")
        if (self.dataset is None) == (self.images is None):
            raise UsageError("give --dataset (a split of shards) or --images (a folder of drawings), one of them")

    def out_path(self) -> str:
        """``out``, or a name after the checkpoint, so evaluating best.pt does not overwrite checkpoint.pt's."""
        ckpt = Path(self.checkpoint)
        what = self.split if self.images is None else f"images-{Path(self.images).resolve().name}"
        return self.out or str(ckpt.with_name(f"eval_{ckpt.stem}_{what}.json"))


def check_evaluate_args(views: int, taus: tuple[float, ...], limit: int | None, points: int | None = None) -> None:
    """UsageError naming the flag of an argument out of range (before any work is done)."""
    if not (isinstance(views, int) and views >= 1):
        raise UsageError(f"views must be an integer >= 1, got {views!r} (--views)")
    if points is not None and not (isinstance(points, int) and points >= 1):
        raise UsageError(f"points must be an integer >= 1 or unset (the run's), got {points!r} (--points)")
    if limit is not None and not (isinstance(limit, int) and limit >= 1):
        raise UsageError(f"limit must be an integer >= 1 or unset (all samples), got {limit!r} (--limit)")
    if not taus or not all(0 < t < math.inf for t in taus):
        raise UsageError(f"tau must be one or more distances > 0, got {list(taus)!r} (--tau)")


@torch.no_grad()
def evaluate(
    checkpoint: str | Path,
    dataset: str | Path,
    split: str = "test",
    category: str | None = None,
    views: int = 1,
    taus: tuple[float, ...] = (0.02, 0.05),
    limit: int | None = None,
    out: str | Path | None = None,
    batch_size: int = 8,
    cad_check: int = 0,
    blind_dataset: str | Path | None = None,
    leave_out: tuple[str, ...] = (),
    variant: int = 0,
    mirror_average: bool = False,
    points: int | None = None,
    steady: bool = False,
) -> dict:
    """Mean metrics of the network and of the template baseline; saved as JSON when ``out``.
    With ``cad_check`` > 0, also the CAD kernel's clean verdict on that many of the network's
    predictions (a second or more each: the kernel intersects the exact surfaces). ``split`` may
    be ``"all"``: every split that has shards. The blind mean is taken over ``blind_dataset``'s
    train split (default ``dataset``'s): on meshes the network never saw, it is its own training
    data's mean output that the network must beat. ``leave_out``: patch labels measured as absent
    in every prediction (model, template and blind alike), for targets known to lack those parts:
    the TORCS car bodies have no wheels (the game adds its own). ``variant``: the pencil variant
    drawn of each view, for the sketches and the blind mean alike. ``mirror_average``: the network
    answers through :class:`train.mirror_average.MirrorAverage`, for the sketches and the blind
    mean alike. ``points``: sample points per shape for the metrics (default: the run's).
    ``steady``: the network answers as ``predict`` does, through
    :class:`train.augmentation.SteadyAverage`, for the sketches and the blind mean alike.
    ``chamfer_vs_template`` and ``chamfer_vs_blind``: the network's L_Ch relative to each baseline's,
    with a bootstrap interval over the evaluated shapes (:func:`train.metrics.relative_change_interval`)."""
    check_evaluate_args(views, taus, limit, points)
    if not (isinstance(cad_check, int) and cad_check >= 0):
        raise UsageError(f"cad_check must be an integer >= 0, got {cad_check!r} (--cad-check)")
    if not (isinstance(variant, int) and variant >= 0):
        raise UsageError(f"variant must be an integer >= 0, got {variant!r} (--variant)")
    run = load_run(checkpoint)
    if mirror_average:
        run = mirror_averaged(run)
    if steady:
        run = dataclasses.replace(run, model=SteadyAverage(run.model).eval())
    s, template, model = run.settings, run.template, run.model
    n_points = points or s.n_points
    try:
        objective = Objective(template, n_points, leave_out=tuple(leave_out))
    except ValueError as exc:
        raise UsageError(f"{exc} (--leave-out)") from None
    names = metric_names(tuple(taus))
    # the same evaluation samples on every call, and for the network as for the template
    baselines = ("model", "template", "blind")
    generators = {name: torch.Generator().manual_seed(0) for name in baselines}
    data = DataSettings(eval_views=views, eval_variant=variant, n_points=n_points, image_size=s.image_size)
    cat = category or s.category
    blind = blind_output(model, blind_dataset or dataset, cat, data, batch_size)[None]
    sums = {name: {k: 0.0 for k in names} for name in baselines}
    chamfers: dict[str, list[torch.Tensor]] = {name: [] for name in baselines}
    count = 0
    base = template.initial_params()[None]
    verdicts = []
    for batch in evaluation_batches(dataset, cat, split, data, batch_size):
        params = model(batch["images"], batch["view_mask"])
        if len(verdicts) < cad_check:
            verdicts += [v.clean for v in cad_verdicts(objective, params[: cad_check - len(verdicts)], batch["meta"])]
        for name, p in (("model", params), ("template", base.expand_as(params)), ("blind", blind.expand_as(params))):
            metrics = batch_metrics(objective, p, batch, tuple(taus), generators[name])
            for k, v in metrics.items():
                sums[name][k] += float(v.sum())
            chamfers[name].append(metrics["chamfer"].detach().cpu())
        count += len(batch["key"])
        if limit and count >= limit:
            break
    result = {
        "checkpoint": str(checkpoint),
        "step": run.step,
        "split": split,
        **({"blind_from": str(blind_dataset)} if blind_dataset else {}),
        **({"left_out": sorted(leave_out)} if leave_out else {}),
        "samples": count,
        "views": views,
        "points": n_points,
        "variant": variant,
        "mirror_average": mirror_average,
        "steady": steady,
        "fscore_taus": list(taus),
        "chamfer_note": "chamfer = paper's unsquared Jacobian-weighted L_Ch; chamfer_sq_x1000 = peers' squared x1000",
        **{name: {k: v / max(count, 1) for k, v in vals.items()} for name, vals in sums.items()},
    }
    if count:
        per_shape = {name: torch.cat(v) for name, v in chamfers.items()}
        for base_name in ("template", "blind"):
            result[f"chamfer_vs_{base_name}"] = relative_change_interval(per_shape["model"], per_shape[base_name])
    if verdicts:
        result["model"]["cad_clean"] = sum(verdicts) / len(verdicts)
        result["cad_checked"] = len(verdicts)
    if out:
        write_json(out, result)
    return result


def evaluation_batches(dataset: str | Path, category: str, split: str, data: DataSettings, batch_size: int):
    """The evaluation batches of one split, or of every split with shards (``split`` "all")."""
    for name in splits_with_shards(dataset, category, split):
        yield from make_loader(dataset, category, name, data, 0, batch_size, train=False)


def format_table(result: dict) -> str:
    cols = [c for c in ("model", "template", "blind") if c in result]
    lines = [f"{'metric':<20}" + "".join(f"{c:>14}" for c in cols)]
    for k in result["model"]:
        lines.append(f"{k:<20}" + "".join(f"{result[c][k]:>14.6g}" if k in result[c] else f"{'-':>14}" for c in cols))
    for base_name in ("template", "blind"):
        if (r := result.get(f"chamfer_vs_{base_name}")) is not None:
            lines.append(
                f"L_Ch vs {base_name}: {100 * r['change']:+.1f} % "
                f"({100 * r['level']:.0f} % bootstrap interval over the {result['samples']} shapes: "
                f"{100 * r['low']:+.1f} to {100 * r['high']:+.1f} %)"
            )
    return "\n".join(lines)
