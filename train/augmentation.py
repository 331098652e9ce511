"""Training-time image jitter (small rotation, crop-and-resize, optional horizontal flip), and at
inference the prediction averaged over small jitters.

Works on 8-bit black-on-white sketches before inversion, so the border it brings in is paper
(white). All randomness comes from the caller's seeded generator.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import torch
import torch.nn.functional as F

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


# Inference: the prediction averaged over small jitters of the sketch (a lightly blurred copy shifted
# by a pixel and scaled by 3 %, 27 copies, one batch). A network trained under jitter still moves
# by a third of the distance between two models for a one-pixel shift; a person's drawing differs
# from a training sketch by such resampling, so predict answers with the average over the jitter.
STEADY_SHIFTS_PX = (-1.0, 0.0, 1.0)
STEADY_SCALES = (0.97, 1.0, 1.03)
STEADY_BLUR_SIGMA = 0.7
STEADY_COPIES = len(STEADY_SHIFTS_PX) ** 2 * len(STEADY_SCALES)


def _blur(images: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of ``(N, 1, S, S)`` images (edges replicated)."""
    k = 2 * int(np.ceil(3 * sigma)) + 1
    t = torch.arange(k, dtype=images.dtype, device=images.device) - k // 2
    w = torch.exp(-0.5 * (t / sigma) ** 2)
    w = w / w.sum()
    pad = k // 2
    out = F.conv2d(F.pad(images, (pad, pad, 0, 0), mode="replicate"), w.view(1, 1, 1, k))
    return F.conv2d(F.pad(out, (0, 0, pad, pad), mode="replicate"), w.view(1, 1, k, 1))


def steady_copies(images: torch.Tensor) -> torch.Tensor:
    """Network inputs ``(B, V, 1, S, S)`` (ink 1, paper 0) -> their jittered copies ``(K, B, V, 1, S, S)``."""
    b, v, c, s, _ = images.shape
    flat = _blur(images.reshape(b * v, c, s, s), STEADY_BLUR_SIGMA)
    copies = []
    for dx in STEADY_SHIFTS_PX:
        for dy in STEADY_SHIFTS_PX:
            for scale in STEADY_SCALES:
                theta = torch.tensor(
                    [[1 / scale, 0.0, -2 * dx / s], [0.0, 1 / scale, -2 * dy / s]], dtype=flat.dtype, device=flat.device
                ).expand(b * v, 2, 3)
                grid = F.affine_grid(theta, list(flat.shape), align_corners=False)
                copies.append(F.grid_sample(flat, grid, align_corners=False, padding_mode="zeros"))
    return torch.stack(copies).reshape(len(copies), b, v, c, s, s)


class SteadyAverage(torch.nn.Module):
    """``model`` answering as ``predict`` does: its output for ``images (B, V, 1, S, S)`` (or
    ``(B, 1, S, S)``) averaged over :func:`steady_copies` (one batch), the view mask repeated for
    each copy."""

    def __init__(self, model: torch.nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, images: torch.Tensor, view_mask: torch.Tensor | None = None) -> torch.Tensor:
        if images.dim() == 4:
            images = images.unsqueeze(1)
        copies = steady_copies(images)
        k, b = copies.shape[:2]
        # copy-major: copy k of item b sits at k * B + b, and so does its mask row
        mask = None if view_mask is None else view_mask.repeat(k, 1)
        out = self.model(copies.reshape(k * b, *copies.shape[2:]), mask)
        return out.reshape(k, b, *out.shape[1:]).mean(0)
