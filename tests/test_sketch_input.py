"""A person's drawing normalized like the training sketches (train/sketch_input.py).

Person-like variants of one clean sketch (transparent PNG, grey-paper JPEG with a gradient,
white on black, off-centre on a large canvas, a non-square canvas, 64×64, a thick marker, 16-bit
TIFF, WebP) must normalize to nearly the clean sketch's image: closer than a quarter of the
distance between two different drawings.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from train.sketch_input import Framing, SketchError, image_stats, measure_framing, normalize_sketch

SIZE = 128


def _drawing(kind: str) -> np.ndarray:
    """A training-like sketch: dark thin lines on white, ~0.78 of the frame, centred."""
    img = np.full((SIZE, SIZE), 255, np.uint8)
    if kind == "knife":
        blade = np.array([[14, 64], [40, 56], [70, 55], [70, 72], [40, 70]], np.int32)
        handle = np.array([[70, 58], [114, 58], [114, 70], [70, 70]], np.int32)
        cv2.polylines(img, [blade, handle], True, 90, 1, cv2.LINE_AA)
    else:  # a mug: a cup and its handle
        cv2.rectangle(img, (30, 20), (84, 108), 90, 1, cv2.LINE_AA)
        cv2.ellipse(img, (57, 20), (27, 6), 0, 0, 360, 90, 1, cv2.LINE_AA)
        cv2.ellipse(img, (88, 64), (14, 22), 0, -90, 90, 90, 2, cv2.LINE_AA)
    return img


def _png(img: np.ndarray, ext: str = ".png", params: tuple = ()) -> bytes:
    return cv2.imencode(ext, img, list(params))[1].tobytes()


def _variants(g: np.ndarray) -> dict[str, bytes]:
    h, w = g.shape
    rgba = np.zeros((h, w, 4), np.uint8)
    rgba[..., 3] = 255 - g  # black ink whose alpha is its darkness, transparent paper
    yy, xx = np.mgrid[0 : h * 4, 0 : w * 4]
    paper = 0.5 + 0.3 * xx / (w * 4) + 0.1 * yy / (h * 4)  # a photo: grey paper, a light gradient
    photo = (cv2.resize(g, (w * 4, h * 4), interpolation=cv2.INTER_LINEAR) / 255.0 * paper * 255).astype(np.uint8)
    canvas = np.full((900, 1200), 255, np.uint8)
    canvas[40 : 40 + 2 * h, 800 : 800 + 2 * w] = cv2.resize(g, (2 * w, 2 * h))
    wide = np.full((h, 3 * w), 255, np.uint8)
    wide[:, 10 : 10 + w] = g
    marker = cv2.erode(cv2.resize(g, (w * 4, h * 4)), np.ones((9, 9), np.uint8))
    return {
        "transparent PNG": _png(rgba),
        "grey-paper JPEG": _png(photo, ".jpg", (cv2.IMWRITE_JPEG_QUALITY, 80)),
        "inverted": _png(255 - g),
        "off-centre on a large canvas": _png(canvas),
        "non-square canvas": _png(wide),
        "64x64": _png(cv2.resize(g, (64, 64), interpolation=cv2.INTER_AREA)),
        "thick marker": _png(marker),
        "16-bit TIFF": _png(g.astype(np.uint16) * 257, ".tiff"),
        "colour WebP": _png(cv2.cvtColor(g, cv2.COLOR_GRAY2BGR), ".webp", (cv2.IMWRITE_WEBP_QUALITY, 100)),
    }


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute difference after a 1-pixel blur (a one-pixel shift of a line is small)."""
    blur = lambda x: cv2.GaussianBlur(x.astype(np.float32) / 255.0, (0, 0), 1.0)  # noqa: E731
    return float(np.abs(blur(a) - blur(b)).mean())


def test_person_like_variants_normalize_to_the_clean_sketch() -> None:
    knife, mug = _drawing("knife"), _drawing("mug")
    clean = normalize_sketch(_png(knife), SIZE).image
    between = _distance(clean, normalize_sketch(_png(mug), SIZE).image)
    far = {}
    for name, data in _variants(knife).items():
        d = _distance(normalize_sketch(data, SIZE, name=name).image, clean)
        if d > 0.25 * between:
            far[name] = round(d / between, 3)
    assert not far, f"variants farther than 1/4 of two drawings' distance: {far}"


def test_variants_without_normalization_are_far() -> None:
    """The test above can fail: read as before (grey + resize), the variants are far apart."""
    knife, mug = _drawing("knife"), _drawing("mug")
    plain = lambda d: cv2.resize(cv2.imdecode(np.frombuffer(d, np.uint8), cv2.IMREAD_GRAYSCALE), (SIZE, SIZE))  # noqa: E731
    between = _distance(plain(_png(knife)), plain(_png(mug)))
    v = _variants(knife)
    for name in ("transparent PNG", "inverted", "grey-paper JPEG"):
        assert _distance(plain(v[name]), knife) > between, name


def test_report_says_what_was_done() -> None:
    g = _drawing("knife")
    r = normalize_sketch(_png(255 - g), SIZE).report
    assert r["inverted"] is True
    x0, y0, x1, y1 = r["crop_box"]
    assert 10 <= x0 < 20 and 110 < x1 <= 118 and 50 <= y0 < y1 <= 76
    assert 0 < r["ink_share"] < 0.1
    s = image_stats(normalize_sketch(_png(g), SIZE).image)
    assert s["extent"] == pytest.approx(Framing().extent, abs=0.03)  # re-framed to the training extent


def test_framing_is_kept() -> None:
    g = _drawing("mug")
    framing = Framing(extent=0.5)
    s = image_stats(normalize_sketch(_png(g), SIZE, framing).image)
    assert s["extent"] == pytest.approx(0.5, abs=0.03)
    measured = measure_framing([normalize_sketch(_png(g), SIZE, framing).image])
    assert measured.extent == pytest.approx(0.5, abs=0.03)


@pytest.mark.parametrize(
    "image",
    [np.full((300, 200), 255, np.uint8), np.full((64, 64), 30, np.uint8), np.full((100, 100), 128, np.uint8)],
    ids=["white", "black", "grey"],
)
def test_blank_image_is_a_clear_error(image: np.ndarray) -> None:
    with pytest.raises(SketchError, match="no drawing found"):
        normalize_sketch(_png(image), SIZE, name="blank.png")


@pytest.mark.parametrize("data,words", [(b"", "empty file"), (b"GIF89a not really", "not a readable image")])
def test_unreadable_image_is_a_clear_error(data: bytes, words: str) -> None:
    with pytest.raises(SketchError, match=words):
        normalize_sketch(data, SIZE, name="x.png")


def test_predictions_of_person_like_variants_stay_with_the_clean_sketch(tmp_path) -> None:
    """Through predict's own input path (load_sketches): each variant's prediction is within a
    quarter of the distance between the predictions for two different drawings; read as before
    (grey + resize), the transparent and inverted drawings are not."""
    import torch

    from train.model import SketchToPatches
    from train.predict import load_sketches
    from train.templates import load_template

    torch.manual_seed(0)
    model = SketchToPatches(load_template("knife").initial_params(), encoder_width=16)
    with torch.no_grad():
        model.out.weight.normal_(0, 0.02)  # an untrained network that still answers each drawing
    model.eval()
    knife, mug = _drawing("knife"), _drawing("mug")
    files = {"clean": _png(knife), "other": _png(mug), **_variants(knife)}
    path = {}
    for i, (name, data) in enumerate(files.items()):  # no extension: the content says what it is
        path[name] = tmp_path / f"sketch{i}"
        path[name].write_bytes(data)

    @torch.no_grad()
    def points(tensor) -> np.ndarray:
        return model(tensor)[0].numpy()

    def dist(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.abs(a - b).mean())

    clean = points(load_sketches([path["clean"]], SIZE).tensor)
    between = dist(clean, points(load_sketches([path["other"]], SIZE).tensor))
    far = {n: round(dist(points(load_sketches([path[n]], SIZE).tensor), clean) / between, 3) for n in _variants(knife)}
    assert all(v <= 0.25 for v in far.values()), far
    plain = lambda d: torch.from_numpy(
        1.0
        - cv2.resize(
            cv2.imdecode(np.frombuffer(d, np.uint8), cv2.IMREAD_GRAYSCALE),  # noqa: E731
            (SIZE, SIZE),
        ).astype(np.float32)[None, None, None]
        / 255.0
    )
    for name in ("transparent PNG", "inverted"):
        assert dist(points(plain(files[name])), clean) > 0.25 * between, name
