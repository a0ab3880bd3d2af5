"""Learn-then-Test pieces (Angelopoulos, Bates, Candès, Jordan, Lei, 2021): certifying parameters chosen from a grid.

Each candidate j gets a null H_j "its risk exceeds the limit" and a p-value from calibration runs; a
procedure controlling the family-wise error at γ rejects a set of nulls, and with probability ≥ 1 − γ
every rejected (certified) candidate meets its limit, so any choice among them does too.

- `rate_above_p`: exact p-value for "failure rate > limit" from a binomial count (LTT's binomial tail);
- `fixed_sequence`: test along an order fixed before the calibration runs are seen, each at level γ,
  stopping at the first non-rejection; the first true null reached is rejected with probability ≤ γ,
  and nothing after it is tested, so the family-wise error is ≤ γ for any dependence between p-values;
- `interleaved_split`: which run indices calibrate and which learn the order (Pareto Testing,
  Laufer-Goldshtein et al., 2023), by index only, so paired runs (same seed) stay on one side;
- `pareto_order`: the learned order: the candidates not beaten in (learn-split p-value, utility),
  most promising p-value first.
"""

from __future__ import annotations

from collections.abc import Sequence
from fractions import Fraction

import numpy as np
from scipy import special

from uqdrive.uq.bounds import check_unit


def rate_above_p(failures: np.ndarray | int, runs: np.ndarray | int, limit: float) -> np.ndarray:
    """p-value for H0 "failure rate > ``limit``": P(Bin(runs, limit) ≤ failures), 1 where there are no runs.

    Under H0 the count is stochastically at least Bin(runs, limit)'s, so P(p ≤ u) ≤ u for every u.
    """
    limit = check_unit("limit", limit)
    failures, runs = np.asarray(failures, np.int64), np.asarray(runs, np.int64)
    if np.any(failures < 0) or np.any(failures > runs):
        raise ValueError(f"need 0 <= failures <= runs, got {failures!r} of {runs!r}")
    return np.asarray(special.bdtr(failures, runs, limit), float)


def fixed_sequence(p_values: np.ndarray, sequence: Sequence[int] | np.ndarray, gamma: float) -> np.ndarray:
    """Which candidates fixed-sequence testing certifies: those before the first p > γ along ``sequence``.

    ``sequence`` lists candidate indices in testing order (candidates not in it are never certified).
    """
    gamma = check_unit("gamma", gamma)
    p, order = np.asarray(p_values, float), np.asarray(sequence, np.int64)
    if order.size and (len(set(order.tolist())) != order.size or order.min() < 0 or order.max() >= p.size):
        raise ValueError(f"the sequence must list distinct candidate indices below {p.size}")
    failed = p[order] > gamma
    reached = order.size if not failed.any() else int(np.argmax(failed))
    certified = np.zeros(p.size, bool)
    certified[order[:reached]] = True
    return certified


def interleaved_split(runs: int, fraction: float) -> np.ndarray:
    """For run indices 0..runs−1: in the calibration part? Index i is iff ⌊(i + 1) f⌋ > ⌊i f⌋.

    The calibration part takes ⌊runs · f⌋ indices spread evenly over any prefix, so cells of different
    lengths split alike and the same index (the same seed) falls on the same side in every cell.
    """
    if not 0 < fraction <= 1:
        raise ValueError(f"the calibration fraction must be in (0, 1], got {fraction!r}")
    f = Fraction(fraction).limit_denominator(10_000)
    i = np.arange(runs)
    return (i + 1) * f.numerator // f.denominator > i * f.numerator // f.denominator


def pareto_order(p_values: np.ndarray, utility: np.ndarray) -> np.ndarray:
    """Candidates no other beats in both a lower p-value and a higher utility, by p-value, then utility (both
    measured on the learn split), then index."""
    p, u = np.asarray(p_values, float), np.asarray(utility, float)
    beaten = (p[None] <= p[:, None]) & (u[None] >= u[:, None]) & ((p[None] < p[:, None]) | (u[None] > u[:, None]))
    front = np.flatnonzero(~beaten.any(1))
    return front[np.lexsort((front, -u[front], p[front]))]
