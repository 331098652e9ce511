"""The envelope pulled back onto the source: closer, still closed, no folds, holes' caps kept."""

from __future__ import annotations

import signal

import numpy as np
import point_cloud_utils as pcu
import pytest
import trimesh

from pipeline.prepare.settings import PrepareSettings
from pipeline.prepare.watertight import FOLD_COS, make_watertight, pull_to_source


def _distances(points: np.ndarray, source: trimesh.Trimesh) -> np.ndarray:
    return pcu.closest_points_on_mesh(
        points, np.asarray(source.vertices, dtype=np.float64), np.asarray(source.faces, dtype=np.int32)
    )[0]


def _parts() -> list[trimesh.Trimesh]:
    # two overlapping boxes and a cylinder: a soup with buried faces, like the procedural models
    parts = [
        trimesh.creation.box((1.0, 0.3, 0.3)),
        trimesh.creation.box((0.2, 0.8, 0.1)),
        trimesh.creation.cylinder(0.08, 0.6, sections=24),
    ]
    parts[2].apply_translation((0.35, 0.0, 0.2))
    return parts


def _assembly() -> trimesh.Trimesh:
    return trimesh.util.concatenate(_parts())


def test_pull_brings_the_envelope_close_and_keeps_it_closed_and_unfolded():
    src = _assembly()
    v, f = make_watertight(src.vertices, src.faces, 2500, 0)
    pulled = pull_to_source(v, f, src.vertices, src.faces, 0.9)
    before, after = _distances(v, src), _distances(pulled, src)
    assert np.median(after) < 0.2 * np.median(before)
    assert trimesh.Trimesh(pulled, f, process=False).is_watertight
    turned = (
        trimesh.Trimesh(v, f, process=False).face_normals * trimesh.Trimesh(pulled, f, process=False).face_normals
    ).sum(axis=1)
    assert (turned > FOLD_COS).all()
    # never into the solid: buried faces do not attract, the closest point is on the outer surface
    assert not any(part.contains(pulled).any() for part in _parts())


def test_thin_wall_keeps_two_sides():
    plate = trimesh.creation.box((1.0, 1.0, 0.02))
    v, f = make_watertight(plate.vertices, plate.faces, 2500, 0)
    pulled = pull_to_source(v, f, plate.vertices, plate.faces, 0.9)
    top, bottom = v[:, 2] > 0.011, v[:, 2] < -0.011
    assert top.any() and bottom.any()
    assert pulled[top, 2].min() >= 0.01 - 1e-9 and pulled[bottom, 2].max() <= -0.01 + 1e-9
    assert np.abs(pulled[top, 2] - 0.01).mean() < 0.2 * np.abs(v[top, 2] - 0.01).mean()


def test_envelope_far_from_the_source_stays_in_place():
    # Stands for a cap Manifold lays over a hole: envelope with no source surface near it. Pulling
    # it onto the hole's rim would collapse it, so beyond 3x the median offset nothing moves.
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    v, f = make_watertight(box.vertices, box.faces, 2500, 0)
    lid = v[:, 2] > 0.45
    v = v.copy()
    v[lid, 2] += 0.2
    pulled = pull_to_source(v, f, box.vertices, box.faces, 0.9)
    assert lid.sum() > 10
    assert np.array_equal(pulled[lid], v[lid])
    rest = _distances(pulled[~lid], box)
    assert np.median(rest) < 0.2 * np.median(_distances(v[~lid], box))


def test_fraction_zero_is_the_envelope_and_settings_bound_it():
    src = _assembly()
    v, f = make_watertight(src.vertices, src.faces, 1000, 0)
    assert pull_to_source(v, f, src.vertices, src.faces, 0.0) is v
    for bad in (1.0, -0.1):
        with pytest.raises(ValueError, match="pull_to_source"):
            PrepareSettings(pull_to_source=bad)


def test_zero_area_envelope_face_does_not_stall_the_fold_guard():
    src = _assembly()
    v, f = make_watertight(src.vertices, src.faces, 1000, 0)
    v = np.vstack([v, v[f[0, 0]], v[f[0, 0]]])  # a zero-area face on two extra copies of a vertex
    f = np.vstack([f, [[f[0, 0], len(v) - 2, len(v) - 1]]])

    def stalled(signum, frame):
        raise TimeoutError("pull_to_source did not return: the fold guard kept flagging the zero-area face")

    previous = signal.signal(signal.SIGALRM, stalled)
    signal.alarm(30)
    try:
        pulled = pull_to_source(v, f, src.vertices, src.faces, 0.9)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    assert np.median(_distances(pulled, src)) < 0.2 * np.median(_distances(v, src))
