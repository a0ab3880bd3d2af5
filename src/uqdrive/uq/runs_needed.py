"""Runs needed: the number of training runs R at which the mean verdict of a method claim (`claims.mean_verdicts`,
the betting tests that decide it) is decided with probability ``POWER``, found by simulating that procedure itself.

Two spreads of the per-run paired differences, both with the claim's observed mean difference:

- **the study's**: R runs resampled with replacement from the runs the study measured (the empirical spread, its
  failures and piles included);
- **the worst**: every run's difference at −1 or +1 with that mean, the most spread any distribution on [−1, 1]
  with that mean has (the variance 1 − Δ², the largest possible), so the betting stakes gain least from it.

Power is estimated from ``sims`` simulated studies at each R (common random numbers across R, so it rises
smoothly); R is found by doubling then bisection, so the figure is the smallest R on that search path whose
estimated power reaches 0.8 (Monte Carlo standard error ≈ 0.03 at 200 simulations). ``None`` past ``MOST``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

POWER = 0.8
SIMS = 200
MOST = 20_000  # the search stops here: "more than 20,000"

Sampler = Callable[[np.random.Generator, tuple[int, int]], np.ndarray]
Decider = Callable[[np.ndarray], np.ndarray]  # [sims, R] differences -> decided (bool) per simulated study


def resampled(differences: np.ndarray) -> Sampler:
    """Draws from the observed per-run differences, with replacement."""
    values = np.asarray(differences, float)
    return lambda rng, size: rng.choice(values, size)


def worst(mean: float) -> Sampler:
    """Differences at ±1 with the given mean: P(+1) = (1 + mean)/2."""
    share = (1 + float(np.clip(mean, -1, 1))) / 2
    return lambda rng, size: np.where(rng.random(size) < share, 1.0, -1.0)


def power(decided: Decider, sampler: Sampler, runs: int, sims: int = SIMS, seed: int = 0) -> float:
    """The share of ``sims`` simulated studies of ``runs`` runs each that the procedure decides."""
    rng = np.random.default_rng([seed, runs])
    return float(np.mean(decided(sampler(rng, (sims, runs)))))


def runs_needed(decided: Decider, sampler: Sampler, sims: int = SIMS, seed: int = 0, most: int = MOST) -> int | None:
    """The fewest R (on a doubling-then-bisection path from 2) at which ``decided`` reaches ``POWER``; None past
    ``most``."""
    low, high = 1, 2
    while power(decided, sampler, high, sims, seed) < POWER:
        if high >= most:
            return None
        low, high = high, min(2 * high, most)
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (low, middle) if power(decided, sampler, middle, sims, seed) >= POWER else (middle, high)
    return high
