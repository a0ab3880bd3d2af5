"""Intervals for a method's rate over its training replicates: the t-interval's coverage by simulation under the
normal model it assumes, and the bounded (Hoeffding relative-entropy) interval's coverage computed exactly for 0/1
replicate estimates and simulated for replicate rates spread by a beta distribution."""

import itertools

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq.replicates import controllers_interval, replicate_bounded_interval, replicate_t_interval


def coverage_interval(covered: int, reps: int, level: float = 0.999) -> tuple[float, float]:
    """Exact (Clopper–Pearson) interval for a simulated coverage rate."""
    tail = (1 - level) / 2
    low = stats.beta.ppf(tail, covered, reps - covered + 1) if covered else 0.0
    high = stats.beta.ppf(1 - tail, covered + 1, reps - covered) if covered < reps else 1.0
    return low, high


@pytest.mark.parametrize("replicates", [2, 3, 5])
def test_t_interval_covers_at_its_level_when_the_replicate_estimates_are_normal(replicates):
    """10,000 sets of estimates: the coverage's own 99.9% interval (±0.007) holds 0.95 (a z-interval, or t with R
    degrees of freedom, would cover 0.80-0.935 at these R)."""
    rng, eta, reps = np.random.default_rng(replicates), 0.6, 10_000
    estimates = rng.normal(eta, 0.06, (reps, replicates))  # 6.7 sd inside [0, 1]
    covered = sum(i.low <= eta <= i.high for i in (replicate_t_interval(x, 0.05) for x in estimates))
    low, high = coverage_interval(covered, reps)
    assert low <= 0.95 <= high


def test_t_interval_reads_the_estimates_and_needs_two():
    result = replicate_t_interval([0.9, 0.95, 1.0], 0.05)
    half = stats.t.ppf(0.975, 2) * 0.05 / np.sqrt(3)
    assert (result.value, result.low, result.high) == pytest.approx((0.95, 0.95 - half, 1.0))
    assert result.replicates == 3 and result.method == "t"
    with pytest.raises(ValueError, match="at least 2 replicate estimates in \\[0, 1\\]"):
        replicate_t_interval([0.9], 0.05)


@pytest.mark.parametrize("replicates", [1, 3, 5, 10])
def test_bounded_interval_covers_exactly_for_zero_one_estimates(replicates):
    """Estimates that are each 0 or 1 (one rollout per replicate, or rates at the ends): the miss probability
    summed over k ~ Bin(R, η), at a fine η grid and both sides of every interval end (where it jumps)."""
    intervals = [replicate_bounded_interval([1.0] * k + [0.0] * (replicates - k), 0.05) for k in range(replicates + 1)]
    ends = np.array([[i.low, i.high] for i in intervals]).ravel()
    etas = np.concatenate([np.linspace(0, 1, 2001), ends - 1e-10, ends + 1e-10])
    etas = etas[(etas >= 0) & (etas <= 1)]
    k = np.arange(replicates + 1)
    outside = np.array([[not i.low <= eta <= i.high for eta in etas] for i in intervals])
    miss = (stats.binom.pmf(k[:, None], replicates, etas[None]) * outside).sum(0)
    assert miss.max() <= 0.05


def test_bounded_interval_covers_when_training_runs_spread_the_rate():
    """Training runs that mostly work and sometimes fail outright: η_r ~ Beta(0.16, 0.04) (mean 0.8, piled at 0 and
    1, the bound's hardest case), each estimated from 19 rollouts; 10 replicates, 10,000 times. The coverage
    (0.9985 here) stays above 0.95, where the interval at γ = 0.3 or 0.6 would not (0.937, 0.878)."""
    rng, reps, eta = np.random.default_rng(11), 10_000, 0.8
    estimates = rng.binomial(19, rng.beta(0.16, 0.04, (reps, 10))) / 19
    covered = sum(i.low <= eta <= i.high for i in (replicate_bounded_interval(x, 0.05) for x in estimates))
    assert coverage_interval(covered, reps)[0] >= 0.95
    assert replicate_bounded_interval([1.0, 1.0, 1.0], 0.05).low == pytest.approx(0.025 ** (1 / 3))


def _poisson_binomial(rates: np.ndarray, rollouts: int) -> np.ndarray:
    """P(pooled safe count = s), s = 0..R·n: each controller's Binomial(n, rate), convolved."""
    pmf = np.array([1.0])
    for rate in rates:
        pmf = np.convolve(pmf, stats.binom.pmf(np.arange(rollouts + 1), rollouts, rate))
    return pmf


SPREADS = {  # these controllers' rates: equal, piled at the ends, bimodal, one failing outright, skewed
    "equal": [0.9, 0.9, 0.9],
    "piled": [1.0, 1.0, 0.0],
    "bimodal": [0.95, 0.1, 0.9],
    "one fails outright": [0.0, 0.97, 0.97],
    "skewed": [0.99, 0.98, 0.6],
    "near one": [1.0, 0.99, 0.98],
}


@pytest.mark.parametrize("spread", SPREADS)
@pytest.mark.parametrize("rollouts", [5, 14, 29])
def test_controllers_interval_misses_their_mean_at_most_gamma_exactly(spread, rollouts):
    """Exact: every pooled count's interval, weighted by its probability under these controllers' unequal rates
    (a Poisson-binomial, computed by convolution here), misses their mean rate with probability ≤ γ, each side ≤ γ/2;
    the equal-rate binomial is the tight case, a spread one is covered more often."""
    rates, gamma = np.asarray(SPREADS[spread]), 0.05
    pmf = _poisson_binomial(rates, rollouts)
    mean = rates.mean()
    bounds = [controllers_interval([[s]], [rollouts * len(rates)], gamma) for s in range(pmf.size)]
    above = sum(p for p, (low, _) in zip(pmf, bounds) if low > mean)
    below = sum(p for p, (_, high) in zip(pmf, bounds) if high < mean)
    assert above <= gamma / 2 + 1e-12 and below <= gamma / 2 + 1e-12, (above, below)


def test_controllers_interval_over_unequal_rollouts_covers_the_uniform_mixture_exactly():
    """Two controllers at two conditions with 5 and 9 rollouts each (Bonferroni over the conditions): the exact miss
    probability of the averaged interval for the conditions' uniform mixture of these controllers' rates, summed
    over every controller's count at every condition, stays ≤ γ."""
    gamma, rollouts = 0.05, [5, 9]
    rates = [[0.9, 0.3], [1.0, 0.5]]  # condition → controller
    mean = np.mean(rates)
    pmfs = [[stats.binom.pmf(np.arange(n + 1), n, p) for p in r] for r, n in zip(rates, rollouts)]
    miss = 0.0
    for a1, a2, b1, b2 in itertools.product(range(6), range(6), range(10), range(10)):
        low, high = controllers_interval([[a1, a2], [b1, b2]], rollouts, gamma)
        if not low <= mean <= high:
            miss += pmfs[0][0][a1] * pmfs[0][1][a2] * pmfs[1][0][b1] * pmfs[1][1][b2]
    assert miss <= gamma


def test_controllers_interval_is_tighter_than_the_methods_when_every_run_was_safe():
    """The committed run's case: two controllers, 14 safe runs of 14 each. The method's interval over two training
    runs reaches down to 0.16; these two controllers' mean is above 0.87."""
    low, high = controllers_interval([[14, 14]], [14], 0.05)
    assert high == 1.0 and 0.87 < low < 0.9
    assert replicate_bounded_interval([1.0, 1.0], 0.05).low < 0.2
    with pytest.raises(ValueError, match="one non-empty list"):
        controllers_interval([[14], []], [14, 14], 0.05)
