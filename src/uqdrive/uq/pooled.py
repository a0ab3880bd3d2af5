"""η̂1 of a mixture of independent cells: the mean of the cells' rates, with Hoeffding's interval.

The paper's "across all weathers" and our unknown conditions (one cell per variant) are
uniform mixtures of cells with different rates. The exact binomial interval does not apply to
a sum of differently distributed outcomes, but Hoeffding's inequality does: the mixture estimate
Σ_v (k_v / n_v) / V is a sum of independent outcomes, outcome i of cell v bounded in
[0, 1 / (V n_v)], so P(|η̂ − η| > θ) ≤ 2 exp(−2θ² / Σ_v n_v (1 / (V n_v))²), i.e.
θ = sqrt(ln(2/γ) / 2 · Σ_v 1 / (V² n_v)) — with equal n per cell, sqrt(ln(2/γ) / (2 Σ n)).
The guarantee assumes each cell's n was fixed in advance (not a sequential stopping time).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Pooled:
    """Mixture rate ``value`` with half-width ``theta``: P(|value − η| > theta) ≤ ``gamma``; ``n`` runs in all."""

    value: float
    theta: float
    n: int
    gamma: float

    @property
    def low(self) -> float:
        return max(0.0, self.value - self.theta)

    @property
    def high(self) -> float:
        return min(1.0, self.value + self.theta)


def pooled(successes: Sequence[int], runs: Sequence[int], gamma: float) -> Pooled:
    """The uniform mixture of cells with ``successes[v]`` safe runs out of ``runs[v]``."""
    if not 0 < gamma < 1:
        raise ValueError(f"gamma={gamma!r} must be in the open interval (0, 1)")
    if len(successes) != len(runs) or not runs:
        raise ValueError(f"need one success count per cell and at least one cell, got {list(successes)}, {list(runs)}")
    if any(n < 1 or not 0 <= k <= n for k, n in zip(successes, runs)):
        raise ValueError(f"every cell needs 0 <= successes <= runs and runs >= 1, got {list(zip(successes, runs))}")
    cells = len(runs)
    value = sum(k / n for k, n in zip(successes, runs)) / cells
    theta = math.sqrt(math.log(2 / gamma) / 2 * sum(1 / (cells**2 * n) for n in runs))
    return Pooled(value, theta, int(sum(runs)), float(gamma))
