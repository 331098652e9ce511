"""Canonical JSON text, fast: exactly the bytes of ``json.dumps(obj, sort_keys=True, indent=1,
default=default)``, written without the standard library's pure-Python indenting encoder.

With ``indent`` set, ``json.dumps`` cannot use its C encoder and spends ~7 µs per number: the
augment stage's strokes.json (~100k coordinates per model) took 0.2 core-s of ~1 to write, the
render stage's 0.06. Stage outputs are hashed and packed byte for byte, so this must match the
standard encoder exactly: same type tests in the same order (str, None, True, False, int, float,
list/tuple, dict, else ``default``), ``float.__repr__`` / ``int.__repr__`` for numbers,
``NaN``/``Infinity`` for non-finite floats, ASCII-escaped strings, sorted keys. What it does not
handle itself (a dict with non-string keys, a cycle) is handed to ``json.dumps``, which either
writes it the same way or raises its usual error.
"""

from __future__ import annotations

import json
from itertools import chain
from json.encoder import encode_basestring_ascii
from typing import Any, Callable

_float_repr = float.__repr__
_int_repr = int.__repr__
_INF = float("inf")
_c_dumps = json.JSONEncoder().encode  # no indent: the C encoder, ", " and ": " separators


class _Unhandled(Exception):
    """Raised inside the fast encoder for what only ``json.dumps`` should write."""


def _float_text(x: float) -> str:
    if x != x:
        return "NaN"
    if x == _INF:
        return "Infinity"
    if x == -_INF:
        return "-Infinity"
    return _float_repr(x)


_NUMBERS = {float, int}  # exact types: bool and other subclasses go the standard way
_SEQUENCES = {list, tuple}


def _numbers_text(items: list | tuple, level: int) -> str | None:
    """A list of numbers, or of non-empty lists of numbers (a stroke's points), through the C
    encoder, whose number text is the same (float.__repr__, NaN, Infinity), then indented by
    plain replacements (its only ", " and "], [" are separators); None for any other list."""
    i0, i1 = "\n" + " " * level, "\n" + " " * (level + 1)
    types = set(map(type, items))
    if types <= _NUMBERS:
        return "[" + i1 + _c_dumps(items)[1:-1].replace(", ", "," + i1) + i0 + "]"
    if not (types <= _SEQUENCES and all(items) and set(map(type, chain.from_iterable(items))) <= _NUMBERS):
        return None
    i2 = "\n" + " " * (level + 2)
    body = _c_dumps(items)[2:-2].replace("], [", i1 + "]," + i1 + "[" + i2).replace(", ", "," + i2)
    return "[" + i1 + "[" + i2 + body + i1 + "]" + i0 + "]"


def _encode(o: Any, level: int, default: Callable[[Any], Any]) -> str:
    t = type(o)
    if t is float:
        return _float_text(o)
    if t is str:
        return encode_basestring_ascii(o)
    if t is list or t is tuple:
        return _encode_list(o, level, default)
    if t is dict:
        return _encode_dict(o, level, default)
    if t is int:
        return _int_repr(o)
    # the standard encoder's order, for None, booleans and subclasses
    if isinstance(o, str):
        return encode_basestring_ascii(o)
    if o is None:
        return "null"
    if o is True:
        return "true"
    if o is False:
        return "false"
    if isinstance(o, int):
        return _int_repr(o)
    if isinstance(o, float):
        return _float_text(o)
    if isinstance(o, (list, tuple)):
        return _encode_list(o, level, default)
    if isinstance(o, dict):
        return _encode_dict(o, level, default)
    return _encode(default(o), level, default)


def _encode_list(o: list | tuple, level: int, default: Callable[[Any], Any]) -> str:
    if not o:
        return "[]"
    text = _numbers_text(o, level)
    if text is not None:
        return text
    inner = "\n" + " " * (level + 1)
    body = ("," + inner).join([_encode(x, level + 1, default) for x in o])
    return "[" + inner + body + "\n" + " " * level + "]"


def _encode_dict(o: dict, level: int, default: Callable[[Any], Any]) -> str:
    if not o:
        return "{}"
    for k in o:
        if type(k) is not str:
            raise _Unhandled  # json.dumps converts (or rejects) such keys; leave it to it
    inner = "\n" + " " * (level + 1)
    sep = "," + inner
    body = sep.join([encode_basestring_ascii(k) + ": " + _encode(v, level + 1, default) for k, v in sorted(o.items())])
    return "{" + inner + body + "\n" + " " * level + "}"


def canonical_dumps(obj: Any, default: Callable[[Any], Any]) -> str:
    """``json.dumps(obj, sort_keys=True, indent=1, default=default)``, same text, faster."""
    try:
        return _encode(obj, 0, default)
    except (_Unhandled, RecursionError):
        return json.dumps(obj, sort_keys=True, indent=1, default=default)
