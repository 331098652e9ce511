"""Contact sheets (grids of labelled images) and deterministic PNG writing."""

from __future__ import annotations

import io
import zlib
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from pipeline.core.atomic import write_bytes

_PAD = 4
_LABEL_H = 14


def as_rgb(image: np.ndarray) -> np.ndarray:
    """uint8 (H, W, 3) from grayscale (H, W), (H, W, 1), RGB, RGBA (composited on white), bool or float in [0, 1]."""
    a = np.asarray(image)
    if a.dtype == bool:
        a = np.where(a, 255, 0).astype(np.uint8)
    elif a.dtype.kind == "f":
        a = np.clip(np.rint(a * 255.0), 0, 255).astype(np.uint8)
    elif a.dtype != np.uint8:
        a = np.clip(a, 0, 255).astype(np.uint8)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4):
        raise ValueError(f"not an image: shape {np.asarray(image).shape}")
    if a.shape[2] == 1:
        return np.repeat(a, 3, axis=2)
    if a.shape[2] == 4:
        alpha = a[..., 3:4].astype(np.float64) / 255.0
        rgb = a[..., :3] * alpha + 255.0 * (1 - alpha)
        return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    return a


def contact_sheet(images: list[np.ndarray], labels: list[str] | None = None, cols: int = 8) -> np.ndarray:
    """Grid of ``images`` (row-major, ``cols`` per row) on white, each with its label below.

    Images may differ in size and kind (grayscale or RGB); each cell is as large as the largest
    image and images are centred in it. Returns uint8 (H, W, 3).
    """
    if labels is not None and len(labels) != len(images):
        raise ValueError(f"{len(labels)} labels for {len(images)} images")
    rgb = [as_rgb(im) for im in images]
    if not rgb:
        return np.full((_PAD * 2, _PAD * 2, 3), 255, np.uint8)
    cols = max(1, min(int(cols), len(rgb)))
    rows = -(-len(rgb) // cols)
    cell_h = max(im.shape[0] for im in rgb)
    cell_w = max(im.shape[1] for im in rgb)
    label_h = _LABEL_H if labels is not None else 0
    step_y, step_x = cell_h + label_h + _PAD, cell_w + _PAD
    sheet = np.full((rows * step_y + _PAD, cols * step_x + _PAD, 3), 255, np.uint8)
    for i, im in enumerate(rgb):
        r, c = divmod(i, cols)
        y = _PAD + r * step_y + (cell_h - im.shape[0]) // 2
        x = _PAD + c * step_x + (cell_w - im.shape[1]) // 2
        sheet[y : y + im.shape[0], x : x + im.shape[1]] = im
    if labels is not None:
        canvas = Image.fromarray(sheet)
        draw = ImageDraw.Draw(canvas)
        font = ImageFont.load_default()
        for i, text in enumerate(labels):
            r, c = divmod(i, cols)
            x = _PAD + c * step_x
            y = _PAD + r * step_y + cell_h + 1
            draw.text((x, y), _fit(draw, font, str(text), cell_w), fill=(0, 0, 0), font=font)
        sheet = np.asarray(canvas, np.uint8).copy()
    return sheet


def _fit(draw: ImageDraw.ImageDraw, font: ImageFont.ImageFont, text: str, width: int) -> str:
    """Shorten ``text`` with an ellipsis until it fits ``width`` pixels."""
    if draw.textlength(text, font=font) <= width:
        return text
    while text and draw.textlength(text + "…", font=font) > width:
        text = text[:-1]
    return text + "…"


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes with fixed encoder settings and no metadata, so equal pixels give equal bytes."""
    a = np.asarray(image)
    if a.ndim == 2 and a.dtype == np.uint8:
        pil = Image.fromarray(a, mode="L")
    elif a.ndim == 3 and a.shape[2] == 4 and a.dtype == np.uint8:
        pil = Image.fromarray(a, mode="RGBA")
    else:
        pil = Image.fromarray(as_rgb(a), mode="RGB")
    buf = io.BytesIO()
    # zlib's run-length strategy: drawings are runs of white and of ink, and it encodes them
    # 2.3x faster than the default strategy at 2 % more bytes (sketches; views 13 % fewer)
    pil.save(buf, format="PNG", compress_level=6, optimize=False, compress_type=zlib.Z_RLE)
    return buf.getvalue()


def save_png(path: str | Path, image: np.ndarray) -> None:
    """Write ``image`` (grayscale, RGB or RGBA uint8; bool/float converted) atomically as PNG."""
    write_bytes(path, encode_png(image))
