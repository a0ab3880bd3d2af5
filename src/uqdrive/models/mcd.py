"""MC dropout posterior: PilotNet with concrete dropout on the inputs of the last three head layers.

As in the paper, the first head layer (the "fourth" FC layer counted from the output) stays
plain; dropout rates are learned (concrete dropout) rather than tuned by grid search.
"""

from __future__ import annotations

import torch
from torch import nn

from uqdrive.data.binning import SteeringBins
from uqdrive.models.concrete_dropout import ConcreteDropout
from uqdrive.models.pilotnet import Architecture
from uqdrive.models.posterior import Posterior, check_draws


class MCDPosterior(Posterior):
    method = "mcd"

    def __init__(self, arch: Architecture, bins: SteeringBins, init_p: float = 0.1, temperature: float = 0.1) -> None:
        super().__init__(arch, bins)
        shapes = arch.head_shapes(bins.num_classes)
        self.head = nn.ModuleList(nn.Linear(i, o) for i, o in shapes)
        self.dropout = nn.ModuleList(ConcreteDropout(i, init_p, temperature) for i, _ in shapes[1:])

    def init_kwargs(self) -> dict:
        return {"temperature": self.dropout[0].temperature}

    def dropout_rates(self) -> list[float]:
        return [d.p.item() for d in self.dropout]

    def train_logits(self, x: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
        """Training pass with relaxed per-element masks (differentiable in the rates): [B, C]."""
        h = torch.relu(self.head[0](self.trunk(x)))
        for k, (drop, layer) in enumerate(zip(self.dropout, self.head[1:])):
            h = layer(drop.relaxed(h, generator))
            if k < len(self.dropout) - 1:
                h = torch.relu(h)
        return h

    def regularizer(self, num_train: int, lengthscale: float) -> torch.Tensor:
        """Concrete dropout's KL term per training frame (weight decay l²/N, dropout term 2/N)."""
        return sum(drop.regularizer(layer, lengthscale**2 / num_train, 2.0 / num_train)
                   for drop, layer in zip(self.dropout, self.head[1:]))

    @torch.no_grad()
    def head_probs(self, features: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        n = check_draws(n)
        h = torch.relu(self.head[0](features))  # no dropout before it: computed once, not n times
        for k, (drop, layer) in enumerate(zip(self.dropout, self.head[1:])):
            h = torch.matmul(h * drop.sample_masks(n, generator), layer.weight.T) + layer.bias
            if k < len(self.dropout) - 1:
                h = torch.relu(h)
        return torch.softmax(h, dim=-1)
