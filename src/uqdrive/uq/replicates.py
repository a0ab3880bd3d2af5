"""A method's rate over the distribution of its training runs: intervals on the replicates' estimates.

A method (a posterior family) is trained R times (replicate r with seed r); replicate r's cell gives η̂_r
from n rollouts. The method's η is the mean over training runs, E[η_r], and E[η̂_r] = η_r when n is fixed,
so the R estimates are independent draws whose mean is η: the spread between training runs and the
rollout noise within each are both in them. Two intervals, by what they assume:

- `replicate_t_interval`: Student's t with R − 1 degrees of freedom; exact if the η̂_r are normal, which
  fails where they pile up at 0 or 1 (identical estimates give a zero-width interval);
- `replicate_bounded_interval`: Hoeffding's (1963) relative-entropy bound for the mean of independent
  variables in [0, 1]; assumes nothing else, and is correspondingly wide with few replicates.

With two or three replicates either is wide: that is how much the training runs leave unknown. What the same
rollouts do support is an answer for *these* trained controllers (`controllers_interval`): the mean of the R fixed
networks' rates, which the rollout noise alone leaves unknown.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from scipy import optimize, special

from uqdrive.uq.bounds import check_unit, clopper_pearson_interval


@dataclasses.dataclass(frozen=True)
class ReplicateInterval:
    """Mean ``value`` of the replicates' estimates and an interval for η at level 1 − ``gamma``."""

    value: float
    low: float
    high: float
    replicates: int
    gamma: float
    method: str


def _estimates(estimates: Sequence[float] | np.ndarray, least: int) -> np.ndarray:
    x = np.asarray(estimates, float)
    if x.ndim != 1 or x.size < least or np.any(~((x >= 0) & (x <= 1))):
        raise ValueError(f"need at least {least} replicate estimates in [0, 1], got {estimates!r}")
    return x


def replicate_t_interval(estimates: Sequence[float] | np.ndarray, gamma: float) -> ReplicateInterval:
    """mean ± t_{R−1}(1 − γ/2) · s / √R, clipped to [0, 1]; coverage 1 − γ if the estimates are i.i.d. normal."""
    gamma = check_unit("gamma", gamma)
    x = _estimates(estimates, 2)
    mean, half = float(x.mean()), float(special.stdtrit(x.size - 1, 1 - gamma / 2) * x.std(ddof=1) / math.sqrt(x.size))
    return ReplicateInterval(mean, max(0.0, mean - half), min(1.0, mean + half), int(x.size), gamma, "t")


def _kl_lower(mean: float, count: int, level: float) -> float:
    """Smallest μ ≤ ``mean`` with count · KL(mean ‖ μ) ≤ ln(1/level) (the root, less its tolerance: kept low)."""
    limit, tiny, tolerance = math.log(1 / level), 1e-300, 1e-13

    def excess(mu: float) -> float:  # decreasing in μ on (0, mean], negative at mean
        above = mean * math.log(mean / mu) if mean > 0 else 0.0
        below = (1 - mean) * math.log((1 - mean) / (1 - mu)) if mean < 1 else 0.0
        return count * (above + below) - limit

    if mean <= 0 or excess(tiny) <= 0:
        return 0.0
    return max(0.0, optimize.brentq(excess, tiny, mean, xtol=tolerance) - tolerance)


def replicate_bounded_interval(estimates: Sequence[float] | np.ndarray, gamma: float) -> ReplicateInterval:
    """Hoeffding's bound for i.i.d. variables in [0, 1]: P(X̄ ≥ μ + t) ≤ exp(−R · KL(μ + t ‖ μ)), and the same below.

    Each side at γ/2, so the interval {μ : R · KL(x̄ ‖ μ) ≤ ln(2/γ)} covers η with probability ≥ 1 − γ for
    every distribution of the replicate estimates on [0, 1]. Works from one replicate on.
    """
    gamma = check_unit("gamma", gamma)
    x = _estimates(estimates, 1)
    mean = float(x.mean())
    low = _kl_lower(mean, x.size, gamma / 2)
    high = 1 - _kl_lower(1 - mean, x.size, gamma / 2)
    return ReplicateInterval(mean, low, high, int(x.size), gamma, "hoeffding-kl")


def controllers_interval(safe: Sequence[Sequence[int]], rollouts: Sequence[int], gamma: float) -> tuple[float, float]:
    """An interval at level 1 − γ for the mean η1 of these trained controllers (each a fixed network with its own
    rate; over several conditions, the uniform mixture of the conditions): ``safe[c][r]`` is how many of controller
    r's first ``rollouts[c]`` runs (fixed in advance) at condition c were safe.

    Every condition with the same rollouts: Clopper–Pearson on the pooled count. The count is a sum of independent
    Bernoullis with unequal rates, which is at least as concentrated as the binomial of the same mean (Hoeffding
    1956), so the binomial's exact interval keeps its level for the mean rate (checked exactly over spreads of
    rates in tests/test_uq_replicates.py). Unequal rollouts: each condition's interval at γ/C, averaged (Bonferroni).
    """
    gamma = check_unit("gamma", gamma)
    if len(safe) != len(rollouts) or not safe or any(not s for s in safe):
        raise ValueError(f"need one non-empty list of safe counts per condition, got {len(safe)} for {len(rollouts)}")
    if len(set(rollouts)) == 1:
        n = rollouts[0] * sum(len(s) for s in safe)
        low, high = clopper_pearson_interval(sum(sum(s) for s in safe), n, gamma)
        return float(low), float(high)
    bounds = [clopper_pearson_interval(sum(s), n * len(s), gamma / len(safe)) for s, n in zip(safe, rollouts)]
    return float(np.mean([b[0] for b in bounds])), float(np.mean([b[1] for b in bounds]))
