"""A person's drawing -> the kind of image the network was trained on.

The training sketches are dark pencil lines on flat white paper, the drawing centred with its
longer side spanning a fixed share of the frame. A user's image may be a transparent PNG, a
photo or scan of grey paper with a light gradient, white-on-black, off-centre on a large canvas,
not square, tiny, or drawn with a thick marker. :func:`normalize_sketch` undoes each of those:

decode (PNG/JPEG/WebP/TIFF, 8/16-bit, alpha over white) -> level the paper (divide by a
smooth estimate of its tone) -> polarity (the paper is the majority of pixels) -> find the ink
-> crop to its box, pad to a square keeping the aspect so the box spans ``framing.extent`` of it,
centred -> resize -> thin strokes wider than the training range, then scale the ink's darkness
to the training median. :class:`Framing` holds what was measured on the shards
(:func:`measure_framing`); a checkpoint keeps it so a prediction matches its own training data.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

# Darkness (0 paper .. 1 black) above which a levelled pixel counts as ink when measuring.
INK_LEVEL = 0.2
# Fewer ink pixels than this share of the image: there is no drawing to read.
MIN_INK_SHARE = 2e-4
# Connected ink specks smaller than this share of the ink are dust, not drawing.
SPECK_SHARE = 0.002
# Erosion passes at most when thinning a heavy stroke.
MAX_THINNING = 12
# Larger images are reduced to this side first (the report's crop box stays in source pixels).
WORK_SIDE = 1024


class SketchError(ValueError):
    """The image cannot be made into a sketch (unreadable, blank)."""


@dataclasses.dataclass(frozen=True)
class Framing:
    """How the training sketches fill their frame: medians over a sample of shard images."""

    extent: float = 0.78  # longer side of the ink's box / frame side
    darkness: float = 0.45  # mean darkness of the ink pixels
    width: float = 1.67  # stroke width in pixels at the network's image size (ink area / skeleton length)

    def __post_init__(self) -> None:
        if not (0.05 < self.extent <= 1.0 and 0 < self.darkness <= 1 and self.width > 0):
            raise ValueError(f"framing {self}: extent in (0.05, 1], darkness in (0, 1], width > 0")


@dataclasses.dataclass(frozen=True)
class Normalized:
    """The image the network sees (8-bit, black on white, size²) and what was done to get it."""

    image: np.ndarray
    report: dict


def decode(data: bytes, name: str = "image") -> np.ndarray:
    """Any image file cv2 reads -> float grey in [0, 1] (paper 1), alpha composited over white."""
    if not data:
        raise SketchError(f"{name}: not a readable image (empty file)")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SketchError(f"{name}: not a readable image (not a PNG, JPEG, WebP or TIFF file)")
    if img.dtype == np.uint8:
        img = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        img = img.astype(np.float32) / 65535.0
    else:
        img = np.clip(img.astype(np.float32), 0.0, 1.0)
    if img.ndim == 2:
        return img
    channels = img.shape[2]
    colour, alpha = (img[..., :3], img[..., 3]) if channels == 4 else (img[..., : min(channels, 3)], None)
    grey = colour[..., 0] if colour.shape[2] == 1 else cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY)
    if alpha is not None:  # a transparent background is paper, not black
        grey = grey * alpha + (1.0 - alpha)
    return grey.astype(np.float32)


def level_paper(grey: np.ndarray) -> tuple[np.ndarray, bool]:
    """Darkness map (0 paper .. 1 ink) with the paper's tone and gradients divided out, and
    whether the drawing was light on dark (then it is inverted first)."""
    inverted = bool(np.median(grey) < 0.5)  # the paper is most of the picture
    if inverted:
        grey = 1.0 - grey
    side = max(grey.shape)
    k = max(3, int(round(side / 24)) | 1)  # wider than a stroke, narrower than the paper's gradients
    # the paper's tone: a closing (max then min) removes dark strokes, a blur smooths what is left
    paper = cv2.morphologyEx(grey, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    paper = cv2.GaussianBlur(paper, (0, 0), k / 2)
    flat = np.clip(grey / np.maximum(paper, 1e-3), 0.0, 1.0)
    dark = 1.0 - flat
    # what is left of the paper's grain: subtract its typical level so blank paper reads 0
    floor = float(np.percentile(dark, 50))
    return np.clip((dark - floor) / max(1.0 - floor, 1e-3), 0.0, 1.0), inverted


def ink_mask(dark: np.ndarray) -> np.ndarray:
    """Ink pixels: above a level set by the drawing's own darkest strokes, specks removed."""
    level = max(0.08, 0.3 * float(np.percentile(dark, 99.9)))
    mask = (dark > level).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return mask.astype(bool)
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.zeros(n, bool)
    keep[1:] = areas >= SPECK_SHARE * areas.sum()
    return keep[labels]


def _skeleton(mask: np.ndarray) -> np.ndarray:
    from skimage.morphology import skeletonize

    return skeletonize(mask)


def stroke_width(mask: np.ndarray) -> float:
    """Mean stroke width in pixels: ink area over the length of its skeleton."""
    length = int(_skeleton(mask).sum())
    return float(mask.sum()) / max(length, 1)


def frame_square(dark: np.ndarray, box: tuple[int, int, int, int], extent: float) -> np.ndarray:
    """The ink box centred in a square whose side makes the box's longer side ``extent`` of it."""
    x0, y0, x1, y1 = box
    long_side = max(x1 - x0, y1 - y0)
    side = max(int(np.ceil(long_side / extent)), 1)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    ox, oy = int(round(cx - side / 2)), int(round(cy - side / 2))
    out = np.zeros((side, side), np.float32)
    # the part of the square that lies on the image (the rest is white paper)
    sx0, sy0 = max(ox, 0), max(oy, 0)
    sx1, sy1 = min(ox + side, dark.shape[1]), min(oy + side, dark.shape[0])
    out[sy0 - oy : sy1 - oy, sx0 - ox : sx1 - ox] = dark[sy0:sy1, sx0:sx1]
    return out


def thin_strokes(square: np.ndarray, size: int, target: float) -> tuple[np.ndarray, int]:
    """``square`` (darkness, any side) resized to ``size``², its strokes first eroded at the finer
    of the two resolutions until their width at ``size`` is near ``target``; returns the resized
    image and the erosion passes made. Eroding before the resize keeps a thick marker's line a
    line (at the network's size a 2-pixel stroke has nothing left to erode)."""
    fine = square if square.shape[0] >= size else cv2.resize(square, (size, size), interpolation=cv2.INTER_LINEAR)

    def shrink(img: np.ndarray) -> np.ndarray:
        if img.shape[0] == size:
            return img
        return cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)

    small, passes = shrink(fine), 0
    kernel = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    while passes < MAX_THINNING:
        mask = small > INK_LEVEL * 0.5
        if not mask.any() or stroke_width(mask) <= 1.4 * target:
            break
        thinner = cv2.erode(fine, kernel)
        if (thinner > INK_LEVEL).sum() < 0.25 * (fine > INK_LEVEL).sum():  # would erase the drawing, not thin it
            break
        fine, passes = thinner, passes + 1
        small = shrink(fine)
    return small, passes


def normalize_sketch(data: bytes, size: int, framing: Framing = Framing(), name: str = "image") -> Normalized:
    """Image file bytes -> the network's input image (uint8, size², black on white) and a report
    of what was done (crop box in source pixels, scale, inverted, ink share, thinning passes)."""
    grey = decode(data, name)
    source_size, f = [int(grey.shape[1]), int(grey.shape[0])], 1.0
    if max(grey.shape) > WORK_SIDE:  # a photo's resolution adds nothing at the network's size
        f = WORK_SIDE / max(grey.shape)
        grey = cv2.resize(
            grey, (max(1, round(grey.shape[1] * f)), max(1, round(grey.shape[0] * f))), interpolation=cv2.INTER_AREA
        )
    dark, inverted = level_paper(grey)
    mask = ink_mask(dark)
    share = float(mask.mean())
    if share < MIN_INK_SHARE:
        raise SketchError(f"{name}: no drawing found (ink covers {100 * share:.3f} % of the image)")
    ys, xs = np.nonzero(mask)
    box = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
    square = frame_square(np.where(cv2.dilate(mask.astype(np.uint8), None) > 0, dark, 0.0), box, framing.extent)
    side = square.shape[0]
    small, passes = thin_strokes(square, size, framing.width)
    ink = small > INK_LEVEL * 0.5
    gain = 1.0
    if ink.any():  # a downscaled thin line is faint; a heavy marker too dark: match the training ink
        gain = framing.darkness / max(float(small[ink].mean()), 1e-3)
        small = np.clip(small * gain, 0.0, 1.0)
    image = np.round(255.0 * (1.0 - small)).astype(np.uint8)
    report = {
        "source_size": source_size,
        "crop_box": [int(round(v / f)) for v in box],
        "scale": size * f / side,
        "inverted": inverted,
        "ink_share": round(share, 6),
        "thinning_passes": passes,
        "darkness_gain": round(gain, 4),
    }
    return Normalized(image, report)


def image_stats(img: np.ndarray) -> dict[str, float]:
    """Extent, ink darkness and stroke width of one training image (uint8, black on white)."""
    dark = 1.0 - img.astype(np.float32) / 255.0
    mask = dark > INK_LEVEL
    if not mask.any():
        return {}
    ys, xs = np.nonzero(mask)
    extent = max(xs.max() - xs.min() + 1, ys.max() - ys.min() + 1) / max(img.shape)
    return {"extent": float(extent), "darkness": float(dark[mask].mean()), "width": stroke_width(mask)}


def measure_framing(images: list[np.ndarray]) -> Framing:
    """The medians of :func:`image_stats` over training images (already at the network's size)."""
    stats = [s for s in (image_stats(i) for i in images) if s]
    if not stats:
        return Framing()
    med = {k: float(np.median([s[k] for s in stats])) for k in ("extent", "darkness", "width")}
    return Framing(extent=min(med["extent"], 1.0), darkness=med["darkness"], width=med["width"])
