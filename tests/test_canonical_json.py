"""pipeline.core.canonical_json writes exactly json.dumps(sort_keys=True, indent=1)'s text."""

from __future__ import annotations

import enum
import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.core.atomic import _json_default, dumps_json
from pipeline.core.canonical_json import canonical_dumps


def standard(obj) -> str:
    return json.dumps(obj, sort_keys=True, indent=1, default=_json_default)


class Kind(enum.IntEnum):
    A = 3


class Text(str):
    pass


def random_doc(rng: np.random.Generator, depth: int = 0):
    """Nested lists/dicts of the values stage files hold, plus the awkward ones."""
    pick = rng.integers(0, 12 if depth < 4 else 7)
    leaves = [
        lambda: float(rng.normal() * 10.0 ** rng.integers(-8, 8)),
        lambda: int(rng.integers(-5, 10**6)),
        lambda: 's\u00e9"\\\n' * int(rng.integers(0, 2)),
        lambda: None,
        lambda: bool(rng.integers(0, 2)),
        lambda: [float("nan"), float("inf"), -float("inf"), 0.0, -0.0][rng.integers(0, 5)],
        lambda: np.float64(rng.normal()),
    ]
    if pick < len(leaves):
        return leaves[pick]()
    if pick == 7:  # a stroke: points of two numbers (the fast path), sometimes with a non-number
        pts = np.round(rng.normal(size=(int(rng.integers(0, 5)), 2)) * 100, 2).tolist()
        if pts and rng.integers(0, 4) == 0:
            pts[0][0] = [None, True, np.float32(1.5), 7][rng.integers(0, 4)]
        return pts
    if pick == 8:
        return [float(x) for x in rng.normal(size=int(rng.integers(0, 4)))] + [1] * int(rng.integers(0, 2))
    if pick == 9:
        return tuple(random_doc(rng, depth + 1) for _ in range(rng.integers(0, 4)))
    if pick == 10:
        return {f"k{rng.integers(0, 50)}": random_doc(rng, depth + 1) for _ in range(rng.integers(0, 5))}
    return [random_doc(rng, depth + 1) for _ in range(rng.integers(0, 4))]


@pytest.mark.parametrize("seed", range(40))
def test_same_text_as_json_dumps_on_random_documents(seed):
    doc = {"views": [random_doc(np.random.default_rng(seed)) for _ in range(6)]}
    assert canonical_dumps(doc, _json_default) == standard(doc)


def test_same_text_for_the_awkward_cases():
    cases = [
        [],
        {},
        [[]],
        [[], [1.0]],
        [[1.0, 2.0], []],
        [[1.5, float("nan")], [float("inf"), -2]],
        [True, 1, 1.0],
        [[True, 2.0]],
        Kind.A,
        [Kind.A, 2.5],
        Text("x"),
        {"a": Text("y")},
        np.arange(6, dtype=np.float32).reshape(3, 2),
        {"p": Path("/a/b")},
        np.int64(4),
        {"b": 1, "a": {"d": [1e-300, 1e300, 5e-324], "c": "\u2603"}},
        (1.0, (2.0, 3.0)),
        [np.float64(0.1), 0.2],
        [[np.float64(0.1), 0.2]],
    ]
    for obj in cases:
        assert canonical_dumps(obj, _json_default) == standard(obj), obj


def test_leaves_what_it_does_not_write_to_json_dumps():
    # non-string keys: json converts them (and would reject mixed ones the same way)
    assert canonical_dumps({1: "a", 2.5: [1.0]}, _json_default) == standard({1: "a", 2.5: [1.0]})
    cyclic: list = []
    cyclic.append(cyclic)
    with pytest.raises(ValueError, match="Circular"):
        canonical_dumps(cyclic, _json_default)
    with pytest.raises(TypeError, match="not JSON serializable"):
        canonical_dumps({"x": object()}, _json_default)


def test_stage_files_are_written_in_the_same_bytes():
    strokes = {
        "out_size": 128,
        "views": [
            {
                "view": 0,
                "variants": [
                    {
                        "variant": k,
                        "width": 1.25,
                        "strokes": np.round(np.random.default_rng(k).normal(size=(3, 7, 2)) * 50, 2).tolist(),
                    }
                    for k in range(4)
                ],
            }
        ],
    }
    assert dumps_json(strokes) == standard(strokes) + "\n"
