"""Training-time image jitter: small rotation, crop-and-resize, optional horizontal flip.

Works on 8-bit black-on-white sketches before inversion, so the border it brings in is paper
(white). All randomness comes from the caller's seeded generator.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from pipeline.core.settings_io import setting


@dataclasses.dataclass(frozen=True)
class Jitter:
    max_rotation_deg: float = 5.0
    min_crop: float = setting(0.9, "the kept square is this fraction of the side or more")
    flip: bool = setting(False, "only where the template is bilaterally symmetric")


def jitter_image(img: np.ndarray, rng: np.random.Generator, jitter: Jitter, flip: bool) -> np.ndarray:
    """Rotate about a random point near the centre and crop a random square, then resize back."""
    size = img.shape[0]
    angle = rng.uniform(-jitter.max_rotation_deg, jitter.max_rotation_deg)
    crop = rng.uniform(jitter.min_crop, 1.0)
    # Crop offsets in pixels; the kept window lies inside the image.
    off = rng.uniform(0.0, (1.0 - crop) * size, size=2)
    centre = (size / 2.0, size / 2.0)
    m = cv2.getRotationMatrix2D(centre, angle, 1.0 / crop)
    # After scaling about the centre, shift so the chosen window maps onto the full image.
    m[:, 2] += (np.array(centre) - off - crop * size / 2.0) / crop
    out = cv2.warpAffine(img, m, (size, size), flags=cv2.INTER_LINEAR, borderValue=255)
    if flip:
        out = np.ascontiguousarray(out[:, ::-1])
    return out
