"""JSON text of rounded point lists, compiled: the bulk of the stroke files.

``points_json(strokes, decimals)`` is the text ``json.dumps([np.round(s, decimals).tolist() for s
in strokes], separators=(",", ":"))`` gives, without making a Python float and list per
coordinate (~100k a model in the augment stage, where ``tolist`` and the encoder took ~50 ms a
model, a fifth of the stage).

Why the digits can be written from integers: ``np.round(x, d)`` is ``rint(x * 10**d) / 10**d``, a
correctly rounded quotient, so it is the double nearest the decimal ``k / 10**d`` (``k`` the
integer ``rint(x * 10**d)``), and Python's shortest round-trip ``repr`` of it is that decimal
with its trailing zeros dropped (one kept after the point): no shorter decimal lies nearer while
``|k| < 2**53``, and for ``d <= 4`` and such values ``repr`` never switches to an exponent. The sign
is the rounded value's own, so ``-0.0`` stays ``-0.0``. Anything else (non-finite values, huge
coordinates, other shapes) goes through the standard encoder.
"""

from __future__ import annotations

import dataclasses
import json
import re
from typing import Callable

import numpy as np

MAX_DECIMALS = 4
_MAX_ABS_UNITS = 2.0**52  # |k| below this: the quotient's repr is the decimal (see above)


def points_json(strokes: list[np.ndarray], decimals: int) -> str:
    """Compact JSON of ``[np.round(s, decimals).tolist() for s in strokes]`` for (K, 2) arrays."""
    arrays = [np.asarray(s, np.float64) for s in strokes]
    if not (0 <= decimals <= MAX_DECIMALS) or any(a.ndim != 2 or a.shape[1] != 2 or len(a) == 0 for a in arrays):
        return _standard(arrays, decimals)
    if not arrays:
        return "[]"
    scale = 10**decimals
    points = np.concatenate(arrays)
    units = np.rint(points * scale)  # what np.round divides by scale
    if not (np.isfinite(units).all() and np.abs(units).max() < _MAX_ABS_UNITS):
        return _standard(arrays, decimals)
    negative = np.signbit(units / scale)  # the rounded value's sign: -0.0 is written "-0.0"
    ends = np.cumsum([len(a) for a in arrays]).astype(np.int64)
    magnitude = np.abs(units).astype(np.int64)
    # a coordinate: sign, integer digits, point, decimals and a separator; a point two of them
    # and its brackets; a stroke its brackets and comma; the outer brackets and the guard's margin
    int_digits = len(str(int(magnitude.max(initial=0)) // scale))
    out = np.empty(len(points) * (2 * (3 + int_digits + max(decimals, 1)) + 2) + 3 * len(arrays) + 66, np.uint8)
    from pipeline.core.points_kernel import write_points  # numba: imported where it is used

    n = write_points(magnitude, negative, ends, scale, decimals, out)
    return out[:n].tobytes().decode("ascii") if n >= 0 else _standard(arrays, decimals)


def _standard(arrays: list[np.ndarray], decimals: int) -> str:
    return json.dumps([np.round(a, decimals).tolist() for a in arrays], separators=(",", ":"))


@dataclasses.dataclass(frozen=True)
class RoundedPoints:
    """A list of (K, 2) strokes that ``pipeline.core.atomic.dumps_json_compact`` writes as
    ``points_json(strokes, decimals)``: what ``[np.round(s, decimals).tolist() for s in strokes]``
    would be written as, at a fraction of the cost."""

    strokes: list
    decimals: int


_TOKEN = re.compile(r'"\\u0000(\d+)"')


def compact_dumps(obj: object, default: Callable[[object], object]) -> str:
    """``json.dumps(obj, sort_keys=True, separators=(",", ":"), default=default)`` with every
    :class:`RoundedPoints` in ``obj`` written by :func:`points_json`: each stands in as a token
    string (a NUL and its number, which no stage writes) that is then replaced by its text."""
    texts: list[str] = []

    def hook(o: object) -> object:
        if isinstance(o, RoundedPoints):
            texts.append(points_json(o.strokes, o.decimals))
            return f"\0{len(texts) - 1}"
        return default(o)

    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=hook)
    if not texts:
        return text
    out, n = _TOKEN.subn(lambda m: texts[int(m.group(1))], text)
    if n != len(texts):
        raise ValueError("a string in the document looks like a RoundedPoints token")
    return out
