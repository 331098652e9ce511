"""Command line: ``python -m train {fit,evaluate,predict,interpolate} ...`` (see docs/train.md)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from typing import TYPE_CHECKING

from pipeline.core.errors import ModelError
from pipeline.core.settings_io import SettingError, add_arguments, from_args, given_fields
from train.errors import UsageError, one_line
from train.losses.weights import add_weight_flags, weights_from_flags
from train.templates import TemplateError

if TYPE_CHECKING:
    from train.fit import FitSettings


def _fit_args(p: argparse.ArgumentParser) -> None:
    from train.fit import FitSettings
    from train.recipes import RECIPES, describe

    # one flag per setting, help from the field; a recipe names the category and the template
    add_arguments(p, FitSettings, skip=OWN_FLAGS, optional=RECIPE_NAMES)
    p.add_argument(
        "--recipe",
        choices=RECIPES,
        default=None,
        help="start from a named recipe, a complete set of settings measured for that category "
        "(the quality table); any flag given overrides its value: " + "; ".join(f"{r}: {describe(r)}" for r in RECIPES),
    )
    add_weight_flags(p)
    p.add_argument("--no-progress", action="store_true")


# FitSettings fields with flags of their own: the loss weights' --w-<term> / --no-<term> (the term table).
OWN_FLAGS = ("weights",)
# Required unless a recipe gives them.
RECIPE_NAMES = ("category", "template")
# predict's fields that --list-parts does without.
PREDICT_LIST_ONLY = ("sketch", "out")


def given_flags(argv: list[str]) -> set[str]:
    """The FitSettings fields whose flags appear in ``argv`` (what the user set, not a default)."""
    from train.fit import FitSettings

    return given_fields(FitSettings, argv, skip=OWN_FLAGS)


def fit_settings(a: argparse.Namespace, given: set[str] | None = None) -> FitSettings:
    """The run's settings from ``fit``'s flags: loss weights are the paper's, then the template
    file's regularizers, then the flags; the matching λ is the template file's unless
    --match-normals is given. With ``--recipe``, the recipe's settings, then the flags in
    ``given`` (those the user typed) on top."""
    from train.fit import FitSettings
    from train.templates import load_template

    if getattr(a, "recipe", None):
        return _recipe_settings(a, given or set())
    missing = [f"--{n}" for n in RECIPE_NAMES if getattr(a, n) is None]
    if missing:
        raise UsageError(f"{' and '.join(missing)} required (or --recipe)")
    from train.fit import with_template_defaults

    tpl = load_template(a.template)
    return with_template_defaults(
        from_args(FitSettings, a, skip=OWN_FLAGS, weights=weights_from_flags(a, tpl.regularizers))
    )


def _recipe_settings(a: argparse.Namespace, given: set[str]) -> FitSettings:
    from train.fit import FitSettings
    from train.losses.weights import weight_overrides
    from train.recipes import dataset_note, recipe

    base = recipe(a.recipe, a.dataset, a.out)
    note = dataset_note(a.recipe, a.dataset) if a.dataset else None
    if note and os.environ.get("RANK", "0") == "0":  # once under torchrun, not once a process
        print(note, file=sys.stderr)
    fields = {f.name for f in dataclasses.fields(FitSettings)} - set(OWN_FLAGS)
    changes = {k: getattr(a, k) for k in given & fields}
    weights = weight_overrides(a)
    if weights:
        changes["weights"] = dataclasses.replace(base.weights, **weights)
    return dataclasses.replace(base, **changes)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m train", description=__doc__)
    sub = parser.add_subparsers(dest="cmd", required=True)
    _fit_args(sub.add_parser("fit", help="train a sketch -> patches network (torchrun for DDP)"))
    from train.evaluate import EvaluateSettings
    from train.interpolate import InterpolateSettings
    from train.predict import PredictSettings

    add_arguments(
        sub.add_parser("evaluate", help="metrics of a checkpoint and of its template on a split"), EvaluateSettings
    )
    add_arguments(
        sub.add_parser("predict", help="patches + OBJ + quad mesh + STEP + IGES + PNG from sketches"),
        PredictSettings,
        optional=PREDICT_LIST_ONLY,
    )
    add_arguments(
        sub.add_parser("interpolate", help="meshes between two predictions (patch and latent space)"),
        InterpolateSettings,
    )
    from train.serve.session import ServeSettings

    add_arguments(
        sub.add_parser("serve", help="the sketch-to-CAD testbed in the browser (the serve extra)"), ServeSettings
    )
    from train.patch_fit import ExportFitSettings

    add_arguments(
        sub.add_parser("export-fit", help="a model's fitted patches (--fit-patches) as STEP + IGES + OBJ + quad mesh"),
        ExportFitSettings,
    )
    argv = sys.argv[1:] if argv is None else list(argv)
    a = parser.parse_args(argv)
    a.given = given_flags(argv) if a.cmd == "fit" else set()
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

        print(json.dumps(fit(fit_settings(a, a.given), progress=not a.no_progress)))
    elif a.cmd == "evaluate":
        from train.evaluate import EvaluateSettings, evaluate, format_table

        e = from_args(EvaluateSettings, a)
        if e.images is not None:
            from train.evaluate_images import evaluate_images, format_rows

            res = evaluate_images(
                e.checkpoint,
                e.images,
                tuple(e.tau),
                e.limit,
                e.out_path(),
                cad_check=e.cad_check > 0,
                mirror_average=e.mirror_average,
                points=e.points,
            )
            print(format_rows(res))
            print(format_table(res))
            print(f"saved {e.out_path()}")
            return
        with torch.no_grad():
            res = evaluate(
                e.checkpoint,
                e.dataset,
                e.split,
                e.category,
                e.views,
                tuple(e.tau),
                e.limit,
                e.out_path(),
                cad_check=e.cad_check,
                blind_dataset=e.blind_from,
                leave_out=tuple(e.leave_out),
                variant=e.variant,
                mirror_average=e.mirror_average,
                points=e.points,
                steady=e.steady,
            )
        print(format_table(res))
        print(f"saved {e.out_path()}")
    elif a.cmd == "predict":
        from train.predict import PredictSettings, predict, verdict_line

        if a.list_parts:
            _list_parts(a.checkpoint, a.json)
            return
        missing = [f"--{n}" for n in PREDICT_LIST_ONLY if getattr(a, n) is None]
        if missing:
            raise UsageError(f"{' and '.join(missing)} required (or --list-parts)")
        p = from_args(PredictSettings, a)
        res = predict(p.checkpoint, list(p.sketch), p.out, p.parts(), p.cad_units(), p.mirror_average)
        if p.json:
            print(json.dumps(res, indent=1))
        # people read stderr: where the files are, then the verdict in words (a mesh can be
        # watertight and still pass through itself)
        print(
            f"wrote {p.out}/: patches.stp patches.igs mesh.obj quads.obj render.png input.png prediction.json",
            file=sys.stderr,
        )
        print(verdict_line(res["clean"], res["problems"]), file=sys.stderr)
    elif a.cmd == "interpolate":
        from train.interpolate import InterpolateSettings, interpolate

        i = from_args(InterpolateSettings, a)
        res = interpolate(i.checkpoint, list(i.sketch_a), list(i.sketch_b), i.out, i.steps)
        print(json.dumps({k: v for k, v in res.items() if k != "params"}))
    elif a.cmd == "serve":
        from train.serve.session import ServeSettings

        settings = from_args(ServeSettings, a)
        from train.serve.app import serve  # a UsageError naming the install when gradio is missing

        serve(settings)
    elif a.cmd == "export-fit":
        from train.patch_fit import ExportFitSettings, export_fit

        e = from_args(ExportFitSettings, a)
        res = export_fit(e)
        print(json.dumps({k: res[k] for k in ("category", "model", "template", "chamfer_fitted", "step", "clean")}))
        print(
            f"wrote {e.out}/: patches.stp patches.igs mesh.obj quads.obj render.png patches.json export.json",
            file=sys.stderr,
        )


def _list_parts(checkpoint: str, as_json: bool) -> None:
    """``predict --list-parts``: the checkpoint's template's optional parts, then exit."""
    from train.fit import load_run
    from train.predict import describe_parts, template_parts

    template = load_run(checkpoint).template
    if as_json:
        print(json.dumps({"template": template.name, "parts": template_parts(template)}, indent=1))
    else:
        print(describe_parts(template))


if __name__ == "__main__":
    sys.exit(main())
