"""Evaluation draws the pencil variant it is asked for (``evaluate --variant``)."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest

from pipeline.core.errors import ModelError
from pipeline.core.schema import POINTS_MEMBER, sketch_name
from train.data import DataSettings, decode_sample, eval_members, variant_member


def _png(gray: int) -> bytes:
    img = np.full((32, 32), gray, np.uint8)
    img[8:24, 15:17] = 0  # a stroke, so the two drawings differ beyond their paper
    return cv2.imencode(".png", img)[1].tobytes()


def _raw(sketches: dict[str, bytes]) -> dict:
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(0).normal(size=(50, 6)).astype(np.float32))
    return {"__key__": "knife_00007", POINTS_MEMBER: buf.getvalue(), **sketches}


def _images(raw: dict, variant: int) -> np.ndarray:
    settings = DataSettings(eval_views=2, eval_variant=variant, n_points=20, image_size=32)
    return np.asarray(decode_sample(raw, settings, np.random.default_rng(0), False, False)["images"])


def test_evaluation_reads_the_requested_variant_of_every_view() -> None:
    both = _raw({sketch_name(v, k): _png(255 if k == 0 else 150 + v) for v in range(2) for k in range(2)})
    only_light = _raw({sketch_name(v, 0): _png(150 + v) for v in range(2)})
    only_dark = _raw({sketch_name(v, 0): _png(255) for v in range(2)})
    assert np.array_equal(_images(both, 1), _images(only_light, 0))
    assert np.array_equal(_images(both, 0), _images(only_dark, 0))
    assert not np.array_equal(_images(both, 0), _images(both, 1))


def test_a_variant_the_dataset_lacks_is_an_error_naming_the_sample() -> None:
    raw = _raw({sketch_name(v, 0): _png(255) for v in range(2)})
    with pytest.raises(ModelError, match="knife_00007.*no pencil variant 1"):
        _images(raw, 1)
    with pytest.raises(ValueError, match="eval_variant"):
        DataSettings(eval_variant=-1)


def test_variant_member_picks_by_the_variant_in_the_name_not_by_position() -> None:
    # the probe and the figure script pick their drawings with it, as evaluation does
    names = [sketch_name(3, 1), sketch_name(3, 0)]
    assert variant_member(names, 0, "knife_00007") == sketch_name(3, 0)
    assert variant_member(names, 1, "knife_00007") == sketch_name(3, 1)
    with pytest.raises(ModelError, match="knife_00007.*no pencil variant 2"):
        variant_member(names, 2, "knife_00007")


def test_eval_members_reads_the_first_views_in_the_tables_order() -> None:
    # evaluate --views N and the figure script read the same drawings through it
    table = {
        0: [sketch_name(0, 0), sketch_name(0, 1)],
        2: [sketch_name(2, 1), sketch_name(2, 0)],
        1: [sketch_name(1, 0)],
    }
    assert eval_members(table, 2, 1, "k") == [sketch_name(0, 1), sketch_name(2, 1)]
    assert eval_members(table, 9, 0, "k") == [sketch_name(0, 0), sketch_name(2, 0), sketch_name(1, 0)]
