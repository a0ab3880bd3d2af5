"""Modified PilotNet for 1x48x64 grayscale frames, split into a deterministic trunk and a head.

PilotNet (Bojarski et al.) has five convolutions (3 of 5x5 stride 2, 2 of 3x3) and fully
connected layers 1164-100-50-10-1. For our 4x smaller input the 5x5 convolutions are padded
(48x64 → 6x8) and the widths scaled down. As in the paper, the trunk (convolutions + first
FC layer) is deterministic; the *head* is the four FC layers after it, the last with one unit
per steering class. The trunk runs once per frame; only the head is sampled.
"""

from __future__ import annotations

from dataclasses import asdict

import torch
from torch import nn

from uqdrive.schema import Count, schema

INPUT_SHAPE = (1, 48, 64)


@schema(frozen=True)
class Architecture:
    """Widths of the network; saved with every model so it can be rebuilt without the config."""

    conv: tuple[Count, Count, Count, Count, Count] = (24, 36, 48, 64, 64)  # PilotNet's 5 convolutions
    features: Count = 128  # first FC layer: the fixed features VI and HMC build on
    hidden: tuple[Count, Count, Count] = (64, 32, 32)  # the head's hidden widths (4 FC layers in all)

    def head_shapes(self, num_classes: int) -> list[tuple[int, int]]:
        """(in, out) of the four head layers."""
        widths = [self.features, *self.hidden, num_classes]
        return list(zip(widths[:-1], widths[1:]))

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


class Trunk(nn.Module):
    """Convolutions + first FC layer (ReLU after each): frame → feature vector."""

    def __init__(self, arch: Architecture) -> None:
        super().__init__()
        c = (INPUT_SHAPE[0], *arch.conv)
        self.convs = nn.Sequential(
            nn.Conv2d(c[0], c[1], 5, stride=2, padding=2),
            nn.ReLU(),  # 48x64 → 24x32
            nn.Conv2d(c[1], c[2], 5, stride=2, padding=2),
            nn.ReLU(),  # → 12x16
            nn.Conv2d(c[2], c[3], 5, stride=2, padding=2),
            nn.ReLU(),  # → 6x8
            nn.Conv2d(c[3], c[4], 3),
            nn.ReLU(),  # → 4x6
            nn.Conv2d(c[4], c[5], 3),
            nn.ReLU(),  # → 2x4
            nn.Flatten(),
        )
        self.fc = nn.Linear(c[5] * 2 * 4, arch.features)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[1:] != INPUT_SHAPE:
            raise ValueError(f"expected frames [B, {', '.join(map(str, INPUT_SHAPE))}], got {list(x.shape)}")
        return torch.relu(self.fc(self.convs(x)))


def sampled_mlp_logits(features: torch.Tensor, layers: list[tuple[torch.Tensor, torch.Tensor]]) -> torch.Tensor:
    """Head logits for k weight samples at once: features [B, F], layers [(W [k, in, out], b [k, out])] → [k, B, C].

    One batched matmul per layer (baddbmm over the sample dimension) instead of a loop over samples.
    """
    w, b = layers[0]
    h = torch.matmul(features, w) + b.unsqueeze(1)
    for w, b in layers[1:]:
        h = torch.baddbmm(b.unsqueeze(1), torch.relu(h), w)
    return h


def init_weights(module: nn.Module, generator: torch.Generator) -> nn.Module:
    """He initialisation of every Linear/Conv layer from `generator` (not the global RNG).

    He (not torch's default, which shrinks the signal ~2x per layer) keeps activations at scale
    through the ten ReLU layers; with torch's default the net sat on the majority class for ~10 epochs.
    """
    for layer in module.modules():
        if isinstance(layer, (nn.Linear, nn.Conv2d)):
            nn.init.kaiming_uniform_(layer.weight, nonlinearity="relu", generator=generator)
            nn.init.zeros_(layer.bias)
    return module
