"""Intervals for a method's rate over its training replicates: the t-interval's coverage by simulation under the
normal model it assumes, and the bounded (Hoeffding relative-entropy) interval's coverage computed exactly for 0/1
replicate estimates and simulated for replicate rates spread by a beta distribution."""

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq.replicates import replicate_bounded_interval, replicate_t_interval


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
