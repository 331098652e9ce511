"""Luigi parameters made from a settings dataclass, and command-line flags made from a task's
parameters: a build setting is typed once, in ``workflows.build_settings.BuildSettings``, and is
then the same parameter for the `luigi` command, `make dataset` and Python callers."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

import luigi

from pipeline.core.settings_io import cli_fields, field_default, field_help, field_types, flag_name

_LUIGI_TYPES = {int: luigi.IntParameter, float: luigi.FloatParameter, bool: luigi.BoolParameter}


def luigi_parameters(cls: type) -> dict[str, luigi.Parameter]:
    """``{parameter name: Luigi parameter}`` for each field of ``cls``: typed, defaulted and
    described by the field; ``metadata["significant"] = False`` keeps it out of task ids."""
    out = {}
    for f in cli_fields(cls):
        default = field_default(f)
        kw: dict[str, Any] = {
            "description": field_help(cls, f) or None,
            "significant": f.metadata.get("significant", True),
        }
        if default is not dataclasses.MISSING:
            kw["default"] = str(default) if isinstance(default, Path) else default
        out[flag_name(f)] = _LUIGI_TYPES.get(field_types(cls)[f.name], luigi.Parameter)(**kw)
    return out


def with_parameters(cls: type):
    """Class decorator: the task gets ``luigi_parameters(cls)`` as its parameters."""

    def add(task: type[luigi.Task]) -> type[luigi.Task]:
        for name, param in luigi_parameters(cls).items():
            setattr(task, name, param)
            param.__set_name__(task, name)  # what a class body does for its attributes
        return task

    return add


def settings_values(cls: type, task: luigi.Task) -> dict[str, Any]:
    """The task's values of the parameters ``luigi_parameters(cls)`` made, by field name."""
    return {f.name: getattr(task, flag_name(f)) for f in cli_fields(cls)}


def add_task_arguments(parser: argparse.ArgumentParser, task: type[luigi.Task]) -> None:
    """One ``--flag`` per parameter of ``task``, as the `luigi` command spells it. Flags not given
    are left out of the namespace, so the task's own defaults apply."""
    for name, param in task.get_params():
        try:  # the default, or the value luigi.cfg gives: what the task gets without the flag
            default = param.task_value(task.get_task_family(), name)
        except luigi.parameter.MissingParameterException:
            default = None
        shown = "" if default in (None, "", False) else f" (default: {default})"
        kw: dict[str, Any] = {
            "dest": name,
            "default": argparse.SUPPRESS,
            "help": ((param.description or "") + shown).strip() or None,
        }
        if isinstance(param, luigi.BoolParameter):
            kw["action"] = "store_true"
        else:
            kw["type"] = (
                int
                if isinstance(param, luigi.IntParameter)
                else float
                if isinstance(param, luigi.FloatParameter)
                else str
            )
        parser.add_argument("--" + name.replace("_", "-"), **kw)
