"""The network's arithmetic on a GPU: fp32, or bfloat16 autocast with channels-last convolutions.

Only the network (encoder and head) changes: its outputs are cast back to fp32 before the loss,
whose geometry (nearest points, crossings, Jacobians) stays in fp32. A CPU run is always fp32:
autocast there would be slower, not faster. ``bench/bench_train_gpu.py`` compares the loss
terms of the two on one batch."""

from __future__ import annotations

import contextlib

import torch

PRECISIONS = ("fp32", "bf16")


def reduced(device: torch.device, precision: str) -> bool:
    """True where ``precision`` asks for bf16 and the device runs it (a GPU)."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    return precision == "bf16" and torch.device(device).type == "cuda"


def network_autocast(device: torch.device, precision: str) -> contextlib.AbstractContextManager:
    """The context the network's forward runs in: bf16 autocast, or nothing."""
    if reduced(device, precision):
        return torch.autocast("cuda", dtype=torch.bfloat16)
    return contextlib.nullcontext()


def place_network(model: torch.nn.Module, device: torch.device, precision: str) -> torch.nn.Module:
    """``model`` on ``device``; its convolution weights channels-last under bf16 on a GPU (the
    tensor-core kernels' layout: the feature maps then follow the weights)."""
    model = model.to(device)
    if reduced(device, precision):
        model = model.to(memory_format=torch.channels_last)
    return model
