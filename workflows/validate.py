"""Checks of a build's parameters, run when a task is made, before anything is scheduled.

Each problem raises BuildParameterError with one line naming the parameter, what is wrong and,
for an unknown category, what the source offers. ``workflows.console`` prints that line (and no
traceback) for the `luigi` command; `make dataset` prints it and exits 2.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from pipeline.core.settings_io import SettingError, flag_name, from_dict
from workflows.build_settings import PART_LABEL_CHOICES, BuildSettings


class BuildParameterError(ValueError):
    """A build parameter is invalid; ``str()`` is the one line to show the user."""


_FIELDS = {f.name: f for f in dataclasses.fields(BuildSettings)}
# the per-stage settings each JSON parameter overrides
_OVERRIDES = {
    "prepare_overrides": "prepare_settings",
    "render_overrides": "render_settings",
    "augment_overrides": "augment_settings",
    "shard_overrides": "shard_settings",
    "fit_overrides": "fit_settings",
}


def flag(field: str) -> str:
    """A BuildSettings field as typed on the command line."""
    return "--" + flag_name(_FIELDS[field]).replace("_", "-")


def build_settings(values: dict[str, Any]) -> BuildSettings:
    """BuildSettings from parameter values by field name; a mistyped one names its flag."""
    try:
        return from_dict(BuildSettings, values)
    except SettingError as exc:
        raise BuildParameterError(_named(exc)) from None


def category_build(s: BuildSettings, category: str) -> BuildSettings:
    """The settings ``category`` is built with (BuildSettings.for_category): under ``--preset
    per-category`` a category without a preset of its name is an error naming ``--preset``."""
    try:
        return s.for_category(category)
    except SettingError as exc:
        raise BuildParameterError(_named(exc)) from None


def _named(exc: SettingError) -> str:
    """The error as one line that starts with the flag: a range error ("views must be ...")
    becomes "--views must be ...", any other "--views: ..."."""
    if exc.field not in _FIELDS:
        return str(exc)
    text = str(exc)
    if text.startswith(exc.field + " "):
        return flag(exc.field) + text[len(exc.field) :]
    return f"{flag(exc.field)}: {text}"


def check_settings(s: BuildSettings) -> None:
    """The source present, every settings JSON parsed and type-checked (numbers are in range
    once a BuildSettings exists: its own check)."""
    if not s.is_procedural and not Path(s.source).is_dir():
        raise BuildParameterError(f"--source {s.source!r} is neither 'procedural' nor a folder")
    for attr, method in _OVERRIDES.items():
        try:
            getattr(s, method)()
        except (ValueError, TypeError) as exc:  # json.JSONDecodeError is a ValueError
            raise BuildParameterError(f"{flag(attr)}: {exc}") from None
    _check_part_labels(s)
    sh = s.shard_settings()
    if sh.max_samples_per_shard < 1 or sh.max_bytes_per_shard < 1 or sh.points < 1:
        raise BuildParameterError(
            "--shard-settings: max_samples_per_shard, max_bytes_per_shard and points must be >= 1"
        )


def _check_part_labels(s: BuildSettings) -> None:
    """The part label flags name a file source's segmentation; the procedural source's parts
    come from the generator, so there they would silently do nothing."""
    if s.is_procedural:
        for attr in ("part_map", "labels_dir"):
            if getattr(s, attr):
                raise BuildParameterError(
                    f"{flag(attr)}: applies to a file source (--source DIR); procedural parts come from the generator"
                )
        return
    if s.labels_dir and not Path(s.labels_dir).is_dir():
        raise BuildParameterError(f"{flag('labels_dir')}: {s.labels_dir!r} is not a folder")
    try:
        s.part_label_settings()
    except ValueError as exc:  # PartMapError is one
        attr = "part_labels" if s.part_labels not in PART_LABEL_CHOICES else "part_map"
        raise BuildParameterError(f"{flag(attr)}: {exc}") from None


def check_fraction(value: float) -> None:
    if not 0.0 <= value <= 1.0:
        raise BuildParameterError(f"--max-failed-fraction must lie in [0, 1], got {value!r}")


def check_categories(s: BuildSettings, categories: list[str]) -> None:
    """Every name is a plain folder name the source offers (a name such as '..' or 'a/b' would
    write outside the dataset folder)."""
    from pipeline.sources.layouts import layout_of

    for name in categories:
        if name in ("", ".", "..") or "/" in name or "\\" in name or name.startswith((".", "_")):
            raise BuildParameterError(f"--categories: {name!r} is not a category name")
    layout = layout_of(s.source)
    offered = layout.categories(s.source)
    also = layout.also_accepts(s.source)
    unknown = [c for c in categories if c not in offered and c not in also]
    if unknown:
        raise BuildParameterError(
            f"--categories: unknown {', '.join(map(repr, unknown))} for source {s.source!r}; "
            f"it has: {', '.join(offered) if offered else 'no category folders'}"
        )
    if not categories:
        raise BuildParameterError(f"source {s.source!r} has no categories (expected <source>/<category>/ folders)")
    if not s.is_procedural:  # listing names only; the procedural source names its own models
        import itertools

        from pipeline.sources.layouts import ModelIdClash, iter_models

        for c in categories:
            try:
                for _ in itertools.islice(iter_models(s.source, c), s.limit):
                    pass
            except ModelIdClash as exc:
                raise BuildParameterError(str(exc)) from None


def check_dataset_dir(s: BuildSettings, categories: list[str]) -> None:
    """No category folder holds shard-named files this build did not write: it would neither
    replace nor delete them, and left there they would be an unlisted part of the dataset."""
    from pipeline.dataset.shards import NotOurFiles, shard_conflicts

    for c in categories:
        cat_dir = Path(s.dataset_dir) / c
        problems = shard_conflicts(cat_dir)
        if problems:
            raise BuildParameterError(str(NotOurFiles(cat_dir, problems)))
