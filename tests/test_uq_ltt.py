"""Learn-then-Test pieces: the binomial-tail p-value against binomial coefficients, fixed-sequence testing's stop at
the first non-rejection, the index split and the learned (Pareto) order."""

import math

import numpy as np
import pytest

from uqdrive.uq.ltt import fixed_sequence, interleaved_split, pareto_order, rate_above_p


def test_rate_above_p_is_the_binomial_lower_tail():
    for failures, runs, limit in ((0, 10, 0.2), (3, 19, 0.2), (5, 40, 0.05), (40, 40, 0.5)):
        tail = sum(math.comb(runs, i) * limit**i * (1 - limit) ** (runs - i) for i in range(failures + 1))
        assert rate_above_p(failures, runs, limit) == pytest.approx(tail, rel=1e-12)
    assert rate_above_p(0, 10, 0.2) == pytest.approx(0.8**10)  # 0.107: 10 runs cannot show autonomy 0.8 at 0.05
    assert rate_above_p(0, 0, 0.2) == 1.0  # no runs, no evidence
    with pytest.raises(ValueError, match="0 <= failures <= runs"):
        rate_above_p(4, 3, 0.2)


def test_fixed_sequence_stops_at_the_first_non_rejection():
    p = np.array([0.01, 0.2, 0.001, 0.03])
    # candidate 2 has the smallest p-value but comes after candidate 1, which is not rejected
    assert fixed_sequence(p, [0, 1, 2, 3], 0.05).tolist() == [True, False, False, False]
    assert fixed_sequence(p, [2, 0, 3, 1], 0.05).tolist() == [True, False, True, True]
    assert fixed_sequence(p, [1, 0, 2, 3], 0.05).tolist() == [False] * 4
    assert fixed_sequence(p, [2, 3], 0.05).tolist() == [False, False, True, True]  # never tested, never certified
    assert fixed_sequence(p, [0, 3, 2], 0.01).tolist() == [True, False, False, False]  # p ≤ γ rejects
    with pytest.raises(ValueError, match="distinct candidate indices below 4"):
        fixed_sequence(p, [0, 0], 0.05)


def test_interleaved_split_depends_on_the_index_only():
    half = interleaved_split(10, 0.5)
    assert np.flatnonzero(half).tolist() == [1, 3, 5, 7, 9]
    assert interleaved_split(19, 1.0).all() and interleaved_split(19, 0.75).sum() == 14
    for fraction in (0.3, 0.5, 0.7, 0.75):
        long = interleaved_split(100, fraction)
        assert long.sum() == math.floor(100 * fraction)
        for n in (7, 19, 38):  # a shorter cell splits its indices exactly as a longer one does
            assert (interleaved_split(n, fraction) == long[:n]).all()
    with pytest.raises(ValueError, match="calibration fraction must be in \\(0, 1\\]"):
        interleaved_split(10, 0.0)


def test_pareto_order_keeps_the_front_by_p_value():
    p = np.array([0.01, 0.01, 0.2, 0.3, 0.5, 0.5])
    utility = np.array([0.5, 0.6, 0.7, 0.65, 0.9, 0.9])
    # 0 is beaten by 1 (same p, more utility), 3 by 2; 4 and 5 tie and both stay, by index
    assert pareto_order(p, utility).tolist() == [1, 2, 4, 5]
