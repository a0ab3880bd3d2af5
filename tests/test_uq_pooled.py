"""The uniform mixture of independent cells with different rates: Hoeffding's interval, its error computed
exactly by convolving the cells' binomial distributions (not simulated)."""

import itertools
import math

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq.pooled import pooled


def exact_miss_probability(rates: tuple[float, ...], runs: tuple[int, ...], gamma: float) -> float:
    """P(|mixture estimate − mean rate| > θ), summing the probability of every outcome (k_1, …, k_V)."""
    pmfs = [stats.binom.pmf(np.arange(n + 1), n, p) for p, n in zip(rates, runs)]
    target = float(np.mean(rates))
    miss = 0.0
    for ks in itertools.product(*(range(n + 1) for n in runs)):
        estimate = pooled(list(ks), list(runs), gamma)
        if abs(estimate.value - target) > estimate.theta:
            miss += math.prod(pmf[k] for pmf, k in zip(pmfs, ks))
    return miss


@pytest.mark.parametrize("runs", [(19, 19, 19), (8, 13, 21)])
@pytest.mark.parametrize(
    "rates", [(1.0, 1.0, 1.0), (1.0, 0.9, 0.5), (0.99, 0.6, 0.05), (0.5, 0.5, 0.5), (0.8, 0.3, 0.95)]
)
def test_mixture_interval_error_is_at_most_gamma_exactly(rates, runs):
    assert exact_miss_probability(rates, runs, 0.05) <= 0.05


def test_equal_cells_reduce_to_hoeffding_over_all_runs_and_bad_input_is_refused():
    p = pooled([19, 10], [19, 19], 0.05)
    assert p.value == pytest.approx((1 + 10 / 19) / 2) and p.n == 38
    assert p.theta == pytest.approx(math.sqrt(math.log(2 / 0.05) / (2 * 38)))
    assert 0 <= p.low <= p.value <= p.high <= 1
    with pytest.raises(ValueError, match="gamma=0 must be in the open interval"):
        pooled([1], [2], 0)
    with pytest.raises(ValueError, match="0 <= successes <= runs"):
        pooled([3], [2], 0.05)
