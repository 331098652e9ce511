"""The compiled skeleton paths give skan's nodes, degrees and paths exactly (the vectorizer's
strokes depend on their order), on drawings with every kind of junction and on odd skeletons."""

from __future__ import annotations

import numpy as np
import pytest
from skan import Skeleton
from skimage.morphology import skeletonize

from augment.settings import VectorizeSettings
from augment.skeleton_graph import skeleton_paths
from augment.vectorize import ink_mask
from tests.test_augment_vectorize import draw, scene


def assert_same_as_skan(skel: np.ndarray) -> int:
    ref = Skeleton(skel)
    got = skeleton_paths(skel)
    np.testing.assert_array_equal(got.coordinates, ref.coordinates)
    np.testing.assert_array_equal(got.degrees, ref.degrees)
    assert got.n_paths == ref.n_paths
    for i in range(ref.n_paths):
        np.testing.assert_array_equal(got.path(i), ref.path(i))
    return ref.n_paths


@pytest.mark.parametrize("seed", range(6))
def test_drawings_match_skan(seed):
    img = draw(scene(seed), thickness=2 + seed % 3)
    skel = skeletonize(ink_mask(img, VectorizeSettings()))
    assert assert_same_as_skan(skel) >= 5  # crossings, corners and a loop: many paths


@pytest.mark.parametrize("seed", range(4))
def test_noise_skeletons_match_skan(seed):
    # Thinned random blobs: dense junction clusters, where the spanning-tree rule matters.
    rng = np.random.default_rng(seed)
    blobs = rng.random((96, 96)) < 0.45
    skel = skeletonize(blobs)
    degrees = skeleton_paths(skel).degrees
    assert (degrees >= 3).sum() > 10
    assert_same_as_skan(skel)


def test_odd_skeletons_match_skan():
    block = np.zeros((8, 8), bool)
    block[2:4, 2:4] = True  # a 2×2 block: every pixel a junction
    assert skeleton_paths(block).degrees.sum() == 2 * 3  # of its 6 links a spanning tree keeps 3
    assert_same_as_skan(block)
    border = np.zeros((6, 6), bool)
    border[0, :] = border[:, 0] = True  # lines on the image border, meeting at a corner
    assert_same_as_skan(border)
    yy, xx = np.mgrid[:24, :24]
    ring = skeletonize(np.abs(np.hypot(yy - 11.5, xx - 11.5) - 7) < 2)  # an isolated loop
    ring[0, 23] = True  # and an isolated pixel (no path)
    got = skeleton_paths(ring)
    assert got.n_paths == 1 and got.path(0)[0] == got.path(0)[-1]
    assert_same_as_skan(ring)


def test_empty_and_single_pixel():
    assert skeleton_paths(np.zeros((5, 5), bool)).n_paths == 0
    one = np.zeros((5, 5), bool)
    one[2, 2] = True
    got = skeleton_paths(one)
    assert got.n_paths == 0 and got.degrees.tolist() == [0]
