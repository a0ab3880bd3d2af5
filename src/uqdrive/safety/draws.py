"""How many posterior draws a controller's frame takes, and what the frame concludes from them.

``fixed`` is the paper's controller: n draws give π(o), the mutual information and the entropy, n more give η̂2
around that π(o) (Chernoff's n for the warning config's θ, γ: |η̂2 − η2| ≤ θ with probability ≥ 1 − γ).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import torch

from uqdrive.schema import Count, OpenUnit, schema
from uqdrive.uq import frame_measures, mutual_information_se

CONFIDENT, UNSURE, DOUBTFUL = 0, 1, 2
"""The η2 tiers a warning controller acts on: η2 ≥ δ1, δ2 ≤ η2 < δ1, η2 < δ2."""


@schema(frozen=True)
class DrawSettings:
    """A frame's posterior draws: ``fixed`` (the paper's n + n) or ``sequential`` (as many as its decisions need,
    each decided with error ≤ ``gamma`` outside an indifference zone of ``theta``; ``look`` draws at a time)."""

    scheme: Literal["fixed", "sequential"] = "fixed"
    theta: OpenUnit = 0.05
    gamma: OpenUnit = 0.05
    look: Count = 8


@dataclass(frozen=True)
class FrameDecision:
    """What one frame's draws give: π(o) (``decision``), η̂2 (NaN where no η2 set was drawn), the η2 ``tier`` for
    thresholds (δ1, δ2) (None where none were asked), mutual information with its standard error, entropy, and
    the number of draws taken."""

    decision: float
    eta2: float
    tier: int | None
    mutual_information: float
    mutual_information_se: float
    entropy: float
    draws: int


Draw = Callable[[int], torch.Tensor]
"""``draw(m)``: m more posterior draws of one frame, class probabilities [m, 1, C], from the frame's generator."""


def eta2_tier(eta2: float, delta1: float, delta2: float) -> int:
    return DOUBTFUL if eta2 < delta2 else UNSURE if eta2 < delta1 else CONFIDENT


def fixed_frame(
    draw: Draw, n: int, centres: torch.Tensor, eps: float, thresholds: tuple[float, float] | None = None
) -> FrameDecision:
    """The paper's frame: 2n draws in one head call, π(o), MI and entropy from the first n, η̂2 from the others."""
    probs = draw(2 * n)
    m = frame_measures(probs, centres, eps, split=n)
    eta2 = float(m.eta2[0])
    return FrameDecision(
        float(m.decision[0]),
        eta2,
        None if thresholds is None else eta2_tier(eta2, *thresholds),
        float(m.mutual_information[0]),
        float(mutual_information_se(probs[:n])[0]),
        float(m.entropy[0]),
        2 * n,
    )
