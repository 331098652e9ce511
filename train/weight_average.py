"""An exponential moving average of a network's weights, the copy a run validates and hands out.

At a constant learning rate the weights keep wandering around a good region (the validation
curve spikes and recovers); their running average sits nearer its middle. Each update moves
every averaged floating-point tensor (parameters and BatchNorm statistics) a fraction
``1 - d`` towards the training network's and copies integer buffers (BatchNorm's step
counters). The decay warms up, ``d = min(decay, (1 + step) / (10 + step))``: with a fixed 0.999
from the first step the random initial weights keep 0.999^step of the average (27 % at step
1,300), and a knife run's average validated far worse than its training weights.
"""

from __future__ import annotations

import copy

import torch


class WeightAverage:
    """The averaged copy ``.model`` of ``model``; ``update(step)`` after every optimizer step.

    The tensor pairs are taken once: the optimizer, BatchNorm and ``load_state_dict`` all change
    the live tensors in place, so each update is one pass over them, no state-dict rebuilding."""

    def __init__(self, model: torch.nn.Module, decay: float):
        if not 0.0 < decay < 1.0:
            raise ValueError(f"weight average decay must be in (0, 1), got {decay}")
        self.decay = decay
        self.model = copy.deepcopy(model).eval()
        self.model.requires_grad_(False)
        live = model.state_dict(keep_vars=True)
        pairs = [(avg, live[name].detach()) for name, avg in self.model.state_dict().items()]
        self._floats = [(a, b) for a, b in pairs if a.is_floating_point()]
        self._others = [(a, b) for a, b in pairs if not a.is_floating_point()]

    def decay_at(self, step: int) -> float:
        """The decay of the update after 0-based ``step`` (a function of the step alone, so a
        resumed run continues it)."""
        return min(self.decay, (1.0 + step) / (10.0 + step))

    @torch.no_grad()
    def update(self, step: int) -> None:
        weight = 1.0 - self.decay_at(step)
        for avg, new in self._floats:
            avg.lerp_(new, weight)
        for avg, new in self._others:
            avg.copy_(new)
