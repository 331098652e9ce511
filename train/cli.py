"""Command line: ``python -m train {fit,evaluate,predict,interpolate} ...`` (see docs/train.md)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from typing import TYPE_CHECKING

from pipeline.core.errors import ModelError
from pipeline.core.settings_io import SettingError, add_arguments, from_args
from train.errors import UsageError, one_line
from train.losses.weights import add_weight_flags, weights_from_flags
from train.templates import TemplateError

if TYPE_CHECKING:
    from train.fit import FitSettings


def _fit_args(p: argparse.ArgumentParser) -> None:
    from train.fit import FitSettings
    from train.recipes import RECIPES, describe

    add_arguments(p, FitSettings, skip=OWN_FLAGS)  # one flag per setting, help from the field
    for action in p._actions:  # a recipe names the category and the template
        if action.dest in RECIPE_NAMES:
            action.required, action.default = False, None
    p.add_argument(
        "--recipe",
        choices=RECIPES,
        default=None,
        help="start from a named recipe, a complete set of settings measured for that category "
        "(BENCHMARKS.md's quality table); any flag given overrides its value: "
        + "; ".join(f"{r}: {describe(r)}" for r in RECIPES),
    )
    add_weight_flags(p)
    p.add_argument("--no-progress", action="store_true")


# FitSettings fields with flags of their own: the loss weights' --w-<term> / --no-<term> (the term table).
OWN_FLAGS = ("weights",)
# Required unless a recipe gives them.
RECIPE_NAMES = ("category", "template")


def given_flags(parser: argparse.ArgumentParser, argv: list[str]) -> set[str]:
    """Destinations of the options that appear in ``argv`` (what the user set, not a default)."""
    given = set()
    for token in argv:
        option = token.split("=", 1)[0]
        action = parser._option_string_actions.get(option)
        if action is not None:
            given.add(action.dest)
    return given


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
    from train.recipes import recipe

    base = recipe(a.recipe, a.dataset, a.out)
    fields = {f.name for f in dataclasses.fields(FitSettings)} - set(OWN_FLAGS)
    changes = {k: getattr(a, k) for k in given & fields}
    weights = weight_overrides(a)
    if weights:
        changes["weights"] = dataclasses.replace(base.weights, **weights)
    return dataclasses.replace(base, **changes)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m train", description=__doc__)
    sub = parser.add_subparsers(dest="cmd", required=True)
    fit_parser = sub.add_parser("fit", help="train a sketch -> patches network (torchrun for DDP)")
    _fit_args(fit_parser)
    from train.evaluate import EvaluateSettings
    from train.interpolate import InterpolateSettings
    from train.predict import PredictSettings

    add_arguments(
        sub.add_parser("evaluate", help="metrics of a checkpoint and of its template on a split"), EvaluateSettings
    )
    add_arguments(
        sub.add_parser("predict", help="patches + OBJ + quad mesh + STEP + IGES + PNG from sketches"), PredictSettings
    )
    add_arguments(
        sub.add_parser("interpolate", help="meshes between two predictions (patch and latent space)"),
        InterpolateSettings,
    )
    argv = sys.argv[1:] if argv is None else list(argv)
    a = parser.parse_args(argv)
    a.given = given_flags(fit_parser, argv) if a.cmd == "fit" else set()
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
            )
        print(format_table(res))
        print(f"saved {e.out_path()}")
    elif a.cmd == "predict":
        from train.predict import PredictSettings, predict

        p = from_args(PredictSettings, a)
        res = predict(p.checkpoint, list(p.sketch), p.out, p.parts(), p.cad_units())
        if p.json:
            print(json.dumps(res, indent=1))
        # people read stderr: where the files are, then the verdict in words (a mesh can be
        # watertight and still pass through itself)
        print(
            f"wrote {p.out}/: patches.stp patches.igs mesh.obj quads.obj render.png input.png prediction.json",
            file=sys.stderr,
        )
        print("prediction is clean" if res["clean"] else "NOT CLEAN: " + "; ".join(res["problems"]), file=sys.stderr)
    elif a.cmd == "interpolate":
        from train.interpolate import InterpolateSettings, interpolate

        i = from_args(InterpolateSettings, a)
        res = interpolate(i.checkpoint, list(i.sketch_a), list(i.sketch_b), i.out, i.steps)
        print(json.dumps({k: v for k, v in res.items() if k != "params"}))


if __name__ == "__main__":
    sys.exit(main())
