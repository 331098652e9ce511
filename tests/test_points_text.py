"""pipeline.core.points_text writes the text json.dumps gives for rounded point lists."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.core.atomic import dumps_json_compact
from pipeline.core.points_text import RoundedPoints, points_json


def _reference(strokes: list[np.ndarray], decimals: int) -> str:
    return json.dumps([np.round(np.asarray(s, float), decimals).tolist() for s in strokes], separators=(",", ":"))


@pytest.mark.parametrize("decimals", [0, 1, 2, 3, 4])
def test_random_strokes_match_the_standard_encoder(decimals: int) -> None:
    rng = np.random.default_rng(decimals)
    for trial in range(200):
        strokes = [rng.uniform(-300.0, 300.0, (int(rng.integers(1, 40)), 2)) for _ in range(int(rng.integers(0, 6)))]
        if trial % 3 == 0:  # exact decimals, whole numbers and their trailing zeros
            strokes = [np.round(s, int(rng.integers(0, 3))) for s in strokes]
        assert points_json(strokes, decimals) == _reference(strokes, decimals)


def test_signs_zeros_and_carries() -> None:
    # -0.001 rounds to -0.0 (written "-0.0"), 9.999 carries to 10.0, 0.1 + 0.2 is not 0.3
    strokes = [np.array([[-0.001, 0.0], [9.999, -9.999], [0.1 + 0.2, 1e-9], [-0.0, 255.995]])]
    for decimals in range(5):
        assert points_json(strokes, decimals) == _reference(strokes, decimals)


def test_what_it_does_not_write_goes_the_standard_way() -> None:
    huge = [np.array([[1e17, 2.0]])]  # beyond exact integer units
    assert points_json(huge, 2) == _reference(huge, 2)
    with_empty = [np.zeros((0, 2)), np.array([[1.0, 2.0]])]
    assert points_json(with_empty, 2) == _reference(with_empty, 2)
    assert points_json([], 2) == "[]"
    not_finite = [np.array([[np.nan, 1.0], [np.inf, -np.inf]])]
    assert points_json(not_finite, 2) == _reference(not_finite, 2) == "[[[NaN,1.0],[Infinity,-Infinity]]]"


def test_documents_with_rounded_points_are_the_compact_canonical_text() -> None:
    rng = np.random.default_rng(7)
    strokes = [rng.uniform(0.0, 128.0, (int(rng.integers(1, 30)), 2)) for _ in range(20)]
    doc = {"views": [{"view": 1, "variants": [{"strokes": RoundedPoints(strokes, 2), "width": np.float64(1.5)}]}]}
    ref = {"views": [{"view": 1, "variants": [{"strokes": [np.round(s, 2).tolist() for s in strokes], "width": 1.5}]}]}
    text = dumps_json_compact(doc)
    assert text == json.dumps(ref, sort_keys=True, separators=(",", ":")) + "\n"
    assert json.loads(text) == ref


def test_a_string_that_looks_like_a_token_is_refused() -> None:
    with pytest.raises(ValueError, match="token"):
        dumps_json_compact({"a": RoundedPoints([np.zeros((1, 2))], 2), "b": "\x000"})
