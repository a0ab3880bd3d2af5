"""Concrete dropout (Gal, Hron & Kendall 2017): dropout whose rate is learned by gradient descent.

Training replaces the Bernoulli mask by its concrete (relaxed Bernoulli) counterpart at
temperature 0.1, so the loss is differentiable in the rate p. At test time we draw **exact
Bernoulli masks** with the learned p (the temperature → 0 limit the relaxation stands for), which
is what MC dropout's variational distribution is.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from uqdrive.schema import ConfigError

EPS = 1e-7


class ConcreteDropout(nn.Module):
    """Per-element dropout on a layer's input with one learned rate for the layer."""

    def __init__(self, width: int, init_p: float = 0.1, temperature: float = 0.1) -> None:
        super().__init__()
        if not 0.0 < init_p < 1.0:
            raise ConfigError(f"model.init_p={init_p} must lie in (0, 1)")
        if not temperature > 0.0:
            raise ConfigError(f"model.temperature={temperature} must be > 0")
        self.width = width
        self.temperature = temperature
        self.p_logit = nn.Parameter(torch.tensor([math.log(init_p) - math.log1p(-init_p)]))

    @property
    def p(self) -> torch.Tensor:
        return torch.sigmoid(self.p_logit)

    def relaxed(self, x: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
        """Training pass: x times a concrete mask drawn per element, rescaled by 1/(1 - p)."""
        return relaxed_dropout(x, self.p, torch.rand(x.shape, generator=generator, dtype=x.dtype), self.temperature)

    def sample_masks(self, n: int, generator: torch.Generator | None) -> torch.Tensor:
        """n Bernoulli masks [n, 1, width] (shared by every frame of a batch), already scaled by 1/(1 - p)."""
        keep = 1.0 - self.p.detach()
        u = torch.rand((n, 1, self.width), generator=generator)
        return (u < keep).to(torch.float32) / keep

    def regularizer(self, layer: nn.Linear, weight_decay: float, dropout_decay: float) -> torch.Tensor:
        """KL term of the layer: l²/N · ||W||² / (1 - p)  +  2/N · width · (p log p + (1 - p) log(1 - p))."""
        squares = layer.weight.pow(2).sum() + layer.bias.pow(2).sum()
        return dropout_regularizer(squares, self.p, self.width, weight_decay, dropout_decay).sum()


def relaxed_dropout(x: torch.Tensor, p: torch.Tensor, u: torch.Tensor, temperature: float) -> torch.Tensor:
    """x times the concrete mask of uniforms u (x's shape), rescaled by 1/(1 - p); p broadcasts against x (one
    rate, or a rate per replicate [R, 1, 1] for x [R, B, width])."""
    drop = torch.sigmoid(
        (torch.log(p + EPS) - torch.log1p(-p + EPS) + torch.log(u + EPS) - torch.log1p(-u + EPS)) / temperature
    )
    return x * (1.0 - drop) / (1.0 - p)


def dropout_regularizer(
    squares: torch.Tensor, p: torch.Tensor, width: int, weight_decay: float, dropout_decay: float
) -> torch.Tensor:
    """Concrete dropout's KL term of a layer from its weights' sum of squares and its rate (elementwise, so a
    replicate's terms [R] from squares [R] and rates [R])."""
    neg_entropy = p * torch.log(p) + (1.0 - p) * torch.log1p(-p)
    return weight_decay * squares / (1.0 - p) + dropout_decay * width * neg_entropy
