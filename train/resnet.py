"""ResNet-18 image encoder (He et al. 2016), written here because torchvision has no CPU build.

Single-channel input (a sketch); the output is the globally average-pooled feature (512-d), or
with ``grid`` > 1 the last stage's features averaged over a grid × grid layout of the image and
laid end to end (where on the page a feature fires survives the pooling).
"""

from __future__ import annotations

import torch
from torch import nn


def last_stage_cells(image_size: int) -> int:
    """Cells a side of the last stage's feature map for ``image_size``² input: the stem's
    convolution and pooling and three stages each halve it (rounding up), 32× in all (128 → 4)."""
    cells = image_size
    for _ in range(5):
        cells = (cells + 1) // 2
    return cells


class BasicBlock(nn.Module):
    """Two 3x3 convolutions with a residual shortcut (1x1 projection when the shape changes)."""

    def __init__(self, in_ch: int, out_ch: int, stride: int = 1):
        super().__init__()
        self.conv1 = nn.Conv2d(in_ch, out_ch, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(out_ch)
        self.conv2 = nn.Conv2d(out_ch, out_ch, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(out_ch)
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or in_ch != out_ch:
            self.shortcut = nn.Sequential(nn.Conv2d(in_ch, out_ch, 1, stride, bias=False), nn.BatchNorm2d(out_ch))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = torch.relu(self.bn1(self.conv1(x)))
        y = self.bn2(self.conv2(y))
        return torch.relu(y + self.shortcut(x))


class ResNet18(nn.Module):
    """ResNet-18: stem, four stages of two BasicBlocks (64, 128, 256, 512 channels), global pool.

    ``width`` scales every stage (``width`` × 1, 2, 4, 8 channels; 64 is ResNet-18 itself): the
    cost of a convolution grows with the square of its channels, so 32 costs about a quarter.
    ``grid``: the last stage is averaged over grid × grid cells of the image (1: globally, as in
    ResNet-18), so the code has 8 × width × grid² features."""

    def __init__(self, in_channels: int = 1, width: int = 64, grid: int = 1):
        super().__init__()
        if width < 1:
            raise ValueError(f"encoder width must be a positive number of channels, got {width}")
        if grid < 1:
            raise ValueError(f"encoder pooling grid must be at least 1 cell a side, got {grid}")
        self.grid = grid
        self.out_features = 8 * width * grid * grid
        self.stem = nn.Sequential(
            nn.Conv2d(in_channels, width, 7, 2, 3, bias=False),
            nn.BatchNorm2d(width),
            nn.ReLU(inplace=True),
            nn.MaxPool2d(3, 2, 1),
        )
        layers = []
        in_ch = width
        for out_ch, stride in ((width, 1), (2 * width, 2), (4 * width, 2), (8 * width, 2)):
            layers += [BasicBlock(in_ch, out_ch, stride), BasicBlock(out_ch, out_ch, 1)]
            in_ch = out_ch
        self.blocks = nn.Sequential(*layers)
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, C, H, W) images -> (N, 8 × width × grid²) codes (512 for ResNet-18)."""
        return torch.flatten(nn.functional.adaptive_avg_pool2d(self.blocks(self.stem(x)), self.grid), 1)
