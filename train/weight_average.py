"""An exponential moving average of a network's weights, the copy a run validates and hands out.

At a constant learning rate the weights keep wandering around a good region (the validation
curve spikes and recovers); their running average sits nearer its middle. Each update moves
every averaged floating-point tensor (parameters and BatchNorm statistics) a fraction
``1 - decay`` towards the training network's, and copies integer buffers (BatchNorm's step
counters). The average starts as a copy of the network, so early on it trails the training
weights by about ``1 / (1 - decay)`` steps.
"""

from __future__ import annotations

import copy

import torch


class WeightAverage:
    """The averaged copy of ``model``; ``update(model)`` after every optimizer step."""

    def __init__(self, model: torch.nn.Module, decay: float):
        if not 0.0 < decay < 1.0:
            raise ValueError(f"weight average decay must be in (0, 1), got {decay}")
        self.decay = decay
        self.model = copy.deepcopy(model).eval()
        self.model.requires_grad_(False)

    @torch.no_grad()
    def update(self, model: torch.nn.Module) -> None:
        mine, theirs = self.model.state_dict(), model.state_dict()
        for name, avg in mine.items():
            new = theirs[name].detach()
            if avg.is_floating_point():
                avg.lerp_(new, 1.0 - self.decay)
            else:
                avg.copy_(new)

    def state_dict(self) -> dict[str, torch.Tensor]:
        return self.model.state_dict()

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.model.load_state_dict(state)
