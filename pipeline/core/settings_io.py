"""Settings dataclasses as the one place a setting is typed: dicts (JSON, checkpoints, job files)
are turned back into settings by ``from_dict``, and command lines are made from the fields by
``add_arguments`` / ``from_args`` (Luigi parameters: ``workflows.params``).

A field is made with ``setting(default, help, flag)``: its help is ``metadata["help"]``, the one
place a setting's command-line help comes from; ``flag`` renames its command-line flag
(``n_points`` is ``--points``).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


class SettingError(ValueError):
    """A value that does not fit a setting; ``field`` names it (``None``: the whole object)."""

    def __init__(self, message: str, owner: str, field: str | None = None) -> None:
        super().__init__(message)
        self.owner, self.field = owner, field


# ---------------------------------------------------------------- types


@functools.lru_cache(maxsize=None)
def field_types(cls: type) -> dict[str, Any]:
    """Each field's resolved type (annotations are strings under ``from __future__``)."""
    return typing.get_type_hints(cls)


def _optional_inner(tp: Any) -> Any | None:
    """``X`` for ``X | None`` / ``Optional[X]``, else None."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return args[0]
    return None


def _kind(tp: Any) -> str:
    inner = _optional_inner(tp)
    if inner is not None:
        return f"{_kind(inner)} or null"
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return "a list"
        return f"a list of {len(args)} values"
    return {bool: "true/false", int: "an integer", float: "a number", str: "a string", Path: "a path"}.get(
        tp, getattr(tp, "__name__", str(tp))
    )


def _convert(owner: str, name: str, tp: Any, value: Any, current: Any = None) -> Any:
    """``value`` as a ``tp``, or SettingError naming ``owner.name``. Lists become tuples, ints
    become floats where a number is expected (so equal settings hash equally), dicts become
    nested settings (overriding ``current`` field by field when it is one)."""

    def bad() -> SettingError:
        return SettingError(f"{owner}.{name} must be {_kind(tp)}, got {value!r}", owner, name)

    inner = _optional_inner(tp)
    if inner is not None:
        if value is None:
            return None
        try:
            return _convert(owner, name, inner, value, current)
        except SettingError:
            if inner in (bool, int, float, str, Path):
                raise bad() from None  # "an integer or null"
            raise
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise bad()
        try:
            return from_dict(tp, value, base=current if isinstance(current, tp) else None)
        except SettingError as exc:  # name the nested setting from the outer one
            raise SettingError(f"{owner}.{name}: {exc}", owner, name) from None
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise bad()
        if len(args) == 2 and args[1] is Ellipsis:
            item_types = [args[0]] * len(value)
        elif len(value) != len(args):
            raise bad()
        else:
            item_types = list(args)
        return tuple(_convert(owner, f"{name}[{i}]", t, v) for i, (t, v) in enumerate(zip(item_types, value)))
    if tp is bool:
        ok = isinstance(value, bool)
    elif tp is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif tp is float:
        if isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        ok = isinstance(value, float)
    elif tp is str:
        ok = isinstance(value, str)
    elif tp is Path:
        if isinstance(value, str):
            return Path(value)
        ok = isinstance(value, Path)
    else:
        ok = True  # a type this module does not know: the class's own checks decide
    if not ok:
        raise bad()
    return value


# ---------------------------------------------------------------- dicts


def from_dict(cls: type[T], data: dict, base: T | None = None) -> T:
    """An instance of the frozen dataclass ``cls`` from ``data`` (e.g. parsed JSON), every value
    type-checked against its field's type; fields not in ``data`` keep ``base``'s values (default:
    the class defaults). Unknown keys, mistyped values and values the class's own checks refuse
    raise SettingError naming the setting."""
    owner = cls.__name__
    if not isinstance(data, dict):
        raise SettingError(f"{owner} must be a JSON object of settings, got {data!r}", owner)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [k for k in data if k not in fields]
    if unknown:
        raise SettingError(f"{owner} has no setting {unknown[0]!r}; it has: {', '.join(fields)}", owner, unknown[0])
    types_ = field_types(cls)
    clean = {}
    for name, value in data.items():
        try:
            clean[name] = _convert(owner, name, types_[name], value, getattr(base, name, None))
        except SettingError as exc:
            exc.field = name  # the setting itself, also when one of its items is wrong
            raise
    try:
        return dataclasses.replace(base, **clean) if base is not None else cls(**clean)
    except TypeError as exc:  # a required field missing
        raise SettingError(f"{owner}: {exc}", owner) from None


def parse_json_object(text: str | dict | None) -> dict:
    """A JSON object given as text (a command-line or Luigi parameter) or already as a dict."""
    if not text:
        return {}
    if isinstance(text, dict):
        return dict(text)
    try:
        value = json.loads(text)
    except ValueError as exc:
        raise ValueError(f"not valid JSON ({exc}): {text!r}") from None
    if not isinstance(value, dict):
        raise ValueError(f"settings overrides must be a JSON object, got {text!r}")
    return value


# ---------------------------------------------------------------- command lines


def setting(
    default: Any = dataclasses.MISSING,
    help: str = "",
    flag: str | None = None,
    positional: bool = False,
    choices: tuple | None = None,
) -> Any:
    """A settings field with its command-line help and, when it differs, its flag name; a
    ``positional`` field is an argument without a flag; ``choices`` are shown and checked by the
    command line (the class checks its values itself, for library callers too)."""
    meta: dict[str, Any] = {"help": help}
    if flag:
        meta["flag"] = flag
    if positional:
        meta["positional"] = True
    if choices is not None:
        meta["choices"] = tuple(choices)
    return dataclasses.field(default=default, metadata=meta)


def field_help(cls: type, field: dataclasses.Field) -> str:
    """The field's command-line help: what ``setting(help=...)`` gave it."""
    return field.metadata.get("help", "")


def flag_name(field: dataclasses.Field) -> str:
    """The field's parameter name on command lines (``--`` + this with ``-`` for ``_``)."""
    return field.metadata.get("flag", field.name)


def field_default(field: dataclasses.Field) -> Any:
    """The default value, or ``dataclasses.MISSING`` for a required field."""
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return field.default


def cli_fields(cls: type, skip: tuple[str, ...] = ()) -> list[dataclasses.Field]:
    """The fields a command line offers: all but ``skip`` and nested settings."""
    types_ = field_types(cls)
    return [f for f in dataclasses.fields(cls) if f.name not in skip and not dataclasses.is_dataclass(types_[f.name])]


def add_arguments(
    parser: argparse.ArgumentParser,
    cls: type,
    skip: tuple[str, ...] = (),
    optional: tuple[str, ...] = (),
    defaults: bool = True,
) -> None:
    """One ``--flag`` per field of ``cls`` (not ``skip``), typed, defaulted and explained by the
    field. Booleans are switches (``--x`` / ``--no-x``), tuples take several values. Required
    fields named in ``optional`` default to None (something else, e.g. a recipe, may give them);
    with ``defaults=False`` a flag not given is left out of the namespace."""
    types_ = field_types(cls)
    for f in cli_fields(cls, skip):
        tp, default = types_[f.name], field_default(f)
        tp = _optional_inner(tp) or tp
        positional = f.metadata.get("positional", False)
        if positional and not defaults:
            continue  # given_fields asks about flags only
        flag = f.name if positional else "--" + flag_name(f).replace("_", "-")
        kw: dict[str, Any] = {"help": field_help(cls, f) or None}
        if not positional:
            kw["dest"] = f.name
        if "choices" in f.metadata:
            kw["choices"] = f.metadata["choices"]
        if not defaults:
            kw["default"] = argparse.SUPPRESS
        elif positional:
            if default is not dataclasses.MISSING:
                kw["default"], kw["nargs"] = default, "?"
        elif default is dataclasses.MISSING:
            if f.name in optional:
                kw["default"] = None
            else:
                kw["required"] = True
        else:
            kw["default"] = default
            if tp is not bool and default not in (None, "", ()):
                kw["help"] = f"{kw['help'] or ''} (default: %(default)s)".strip()
        if tp is bool:
            kw["action"] = argparse.BooleanOptionalAction
        elif typing.get_origin(tp) is tuple:
            args = typing.get_args(tp)
            kw["type"] = args[0]
            empty = default is dataclasses.MISSING or default in ((), None)
            if len(args) == 2 and args[1] is Ellipsis:
                kw["nargs"] = "+" if default is dataclasses.MISSING else "*"
                if empty and not positional:  # --x A --x B means both; a non-empty default is replaced, not grown
                    kw["action"] = "extend"
                    if kw.get("default") == ():
                        kw["default"] = []  # extend grows a list; from_dict makes it a tuple again
            else:
                kw["nargs"] = len(args)
        else:
            kw["type"] = tp if tp in (int, float, Path) else str
        parser.add_argument(flag, **kw)


def given_fields(cls: type, argv: list[str], skip: tuple[str, ...] = ()) -> set[str]:
    """The fields of ``cls`` whose flags appear in ``argv``: what the user set, not a default."""
    probe = argparse.ArgumentParser(add_help=False)
    add_arguments(probe, cls, skip, defaults=False)
    known, _ = probe.parse_known_args(argv)
    return set(vars(known))


def from_args(cls: type[T], args: argparse.Namespace, skip: tuple[str, ...] = (), **extra: Any) -> T:
    """The settings a namespace filled by ``add_arguments(parser, cls, skip)`` holds, plus ``extra``."""
    data = {f.name: getattr(args, f.name) for f in cli_fields(cls, skip)}
    return from_dict(cls, {**data, **extra})
