"""Command line: ``python -m train {fit,evaluate,predict,interpolate} ...`` (see docs/train.md)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from typing import TYPE_CHECKING

from pipeline.core.errors import ModelError
from pipeline.core.schema import SPLITS
from pipeline.core.settings_io import SettingError, add_arguments, from_args
from train.errors import UsageError, one_line
from train.export.units import DEFAULT_MODEL_UNIT_MM, DEFAULT_UNITS, MM_PER_UNIT, CadUnits
from train.losses.weights import add_weight_flags, weights_from_flags
from train.templates import TemplateError

if TYPE_CHECKING:
    from train.fit import FitSettings


def _fit_args(p: argparse.ArgumentParser) -> None:
    from train.fit import FitSettings

    add_arguments(p, FitSettings, skip=TEMPLATE_DEFAULTS)  # one flag per setting, help from the field
    # added by hand so its default can come from the template file; the help is the field's
    field = {f.name: f for f in dataclasses.fields(FitSettings)}["match_normals"]
    p.add_argument("--match-normals", type=float, default=None, help=field.metadata["help"])
    add_weight_flags(p)
    p.add_argument("--no-progress", action="store_true")


# Training settings whose defaults come from the template file; the command line overrides them.
TEMPLATE_DEFAULTS = ("weights", "match_normals")


def fit_settings(a: argparse.Namespace) -> FitSettings:
    """The run's settings from ``fit``'s flags: loss weights are the paper's, then the template
    file's regularizers, then the flags; the matching λ is the template file's unless
    --match-normals is given."""
    from train.fit import FitSettings
    from train.templates import load_template

    tpl = load_template(a.template)
    return from_args(FitSettings, a, skip=TEMPLATE_DEFAULTS, weights=weights_from_flags(a, tpl.regularizers),
                     match_normals=tpl.match_normals if a.match_normals is None else a.match_normals)


def _parts(items: list[str]) -> dict[str, bool]:
    out = {}
    for item in items:
        name, _, state = item.partition("=")
        if state not in ("on", "off"):
            raise UsageError(f"--part {item}: use NAME=on or NAME=off")
        out[name] = state == "on"
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m train", description=__doc__)
    sub = parser.add_subparsers(dest="cmd", required=True)
    _fit_args(sub.add_parser("fit", help="train a sketch -> patches network (torchrun for DDP)"))
    ev = sub.add_parser("evaluate", help="metrics of a checkpoint and of its template on a split")
    ev.add_argument("--checkpoint", required=True)
    ev.add_argument("--dataset", required=True)
    ev.add_argument("--split", default="test", choices=SPLITS)
    ev.add_argument("--category", default=None, help="default: the run's category")
    ev.add_argument("--views", type=int, default=1)
    ev.add_argument("--tau", type=float, nargs="+", default=[0.02, 0.05], help="F-score distance thresholds (unit-sphere frame)")
    ev.add_argument("--limit", type=int, default=None, help="evaluate at most this many samples")
    ev.add_argument("--out", default=None, help="JSON path (default: next to the checkpoint)")
    pr = sub.add_parser("predict", help="patches + OBJ + quad mesh + IGES + PNG from sketches")
    pr.add_argument("--checkpoint", required=True)
    pr.add_argument("--sketch", nargs="+", required=True, help="one or more views of the same object")
    pr.add_argument("--out", required=True)
    pr.add_argument("--part", action="append", default=[], help="toggle an optional part, e.g. turbine=off")
    pr.add_argument("--units", default=DEFAULT_UNITS, choices=sorted(MM_PER_UNIT), help="length unit declared in patches.stp / patches.igs")
    pr.add_argument("--scale", type=float, default=None,
                    help=f"CAD file units per model unit (default: {DEFAULT_MODEL_UNIT_MM:g} mm in --units, ~20 cm across)")  # fmt: skip
    it = sub.add_parser("interpolate", help="meshes between two predictions (patch and latent space)")
    it.add_argument("--checkpoint", required=True)
    it.add_argument("--sketch-a", nargs="+", required=True)
    it.add_argument("--sketch-b", nargs="+", required=True)
    it.add_argument("--steps", type=int, default=5)
    it.add_argument("--out", required=True)
    a = parser.parse_args(argv)
    try:
        _run(a)
    except (UsageError, SettingError, TemplateError, ModelError) as exc:
        # a mistake in a flag or a file (ModelError: a bad sample in a shard): one line, like
        # argparse's own errors, and its exit status
        print(f"{parser.prog} {a.cmd}: error: {one_line(exc)}", file=sys.stderr)
        return 2
    return 0


def _run(a: argparse.Namespace) -> None:
    """Run the parsed command."""
    import torch

    if a.cmd == "fit":
        from train.fit import fit

        print(json.dumps(fit(fit_settings(a), progress=not a.no_progress)))
    elif a.cmd == "evaluate":
        from pathlib import Path

        from train.evaluate import evaluate, format_table

        # named after the checkpoint too, so evaluating best.pt does not overwrite checkpoint.pt's
        ckpt = Path(a.checkpoint)
        out = a.out or str(ckpt.with_name(f"eval_{ckpt.stem}_{a.split}.json"))
        with torch.no_grad():
            res = evaluate(a.checkpoint, a.dataset, a.split, a.category, a.views, tuple(a.tau), a.limit, out)
        print(format_table(res))
        print(f"saved {out}")
    elif a.cmd == "predict":
        from train.predict import predict

        try:
            units = CadUnits(a.units, a.scale)
        except ValueError as exc:
            raise UsageError(f"--units/--scale: {exc}") from exc
        res = predict(a.checkpoint, a.sketch, a.out, _parts(a.part), units)
        print(json.dumps(res, indent=1))
        # the verdict last, in words: a mesh can be watertight and still pass through itself
        print("prediction is clean" if res["clean"] else "NOT CLEAN: " + "; ".join(res["problems"]))
    elif a.cmd == "interpolate":
        from train.interpolate import interpolate

        res = interpolate(a.checkpoint, a.sketch_a, a.sketch_b, a.out, a.steps)
        print(json.dumps({k: v for k, v in res.items() if k != "params"}))


if __name__ == "__main__":
    sys.exit(main())
