"""The one interface every Bayesian controller is used through: `Posterior.sample_probs(x, n)`.

A posterior is a deterministic trunk (run once per frame batch) plus a Bayesian head (run
for n weight draws at once, vectorised over a sample dimension). Callers that already hold
trunk outputs (e.g. a sweep over n) use `features` + `head_probs` and skip the trunk.

Draws are only promised to be exact *per frame*: MCD and HMC share draw s across the frames
of a batch, VI draws its pre-activations per frame (local reparameterisation, same per-frame
distribution, ~100x fewer random numbers). No consumer may rely on draw s being the same
network for two frames.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

import torch
from torch import nn

from uqdrive.data.binning import SteeringBins
from uqdrive.models.pilotnet import Architecture, Trunk


class Posterior(nn.Module, ABC):
    """Trunk + Bayesian head over the steering classes of `bins`."""

    method: ClassVar[str]

    def __init__(self, arch: Architecture, bins: SteeringBins) -> None:
        super().__init__()
        self.arch = arch
        self.bins = bins
        self.trunk = Trunk(arch)

    @property
    def num_classes(self) -> int:
        return self.bins.num_classes

    def init_kwargs(self) -> dict:
        """Constructor arguments beyond (arch, bins) needed to rebuild this object from a checkpoint."""
        return {}

    @torch.no_grad()
    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Deterministic trunk: frames [B, 1, 48, 64] in [0, 1] → features [B, F]."""
        return self.trunk(x)

    @abstractmethod
    def head_probs(self, features: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """Softmax class probabilities [n, B, C] for n posterior draws of the head."""

    @torch.no_grad()
    def sample_probs(self, x: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """Softmax class probabilities [n, B, C] of n posterior draws for frames x [B, 1, 48, 64]."""
        return self.head_probs(self.features(x), n, generator)


def check_draws(n: int) -> int:
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"number of posterior draws n={n!r} must be a positive integer")
    return n
