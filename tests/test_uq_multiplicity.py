"""The Bonferroni split of γ over a family of cells with each fixed-n Clopper–Pearson cell's error computed exactly
(binomial sums at every jump of the error, here)."""

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq import clopper_pearson_n
from uqdrive.uq.multiplicity import split_gamma


def worst_miss(n: int, theta: float) -> float:
    """sup over η of P(|k/n − η| > θ), k ~ Bin(n, η): the error is quasi-convex between jumps (η = k/n ± θ),
    so its supremum is a one-sided limit at a jump or an end; evaluated on both sides of every jump."""
    k = np.arange(n + 1)
    jumps = np.concatenate([k / n - theta, k / n + theta])
    etas = np.concatenate([jumps - 1e-10, jumps + 1e-10, [0.0, 1.0], np.linspace(0, 1, 501)])
    etas = etas[(etas >= 0) & (etas <= 1)]
    outside = np.abs(k[:, None] / n - etas[None]) > theta
    return float((stats.binom.pmf(k[:, None], n, etas[None]) * outside).sum(0).max())


@pytest.mark.parametrize("thetas", [(0.25,) * 6, (0.1, 0.2, 0.25, 0.3)])
def test_a_family_of_cells_at_gamma_over_m_is_within_its_thetas_together_with_probability_1_minus_gamma(thetas):
    """Whatever the dependence between the cells, the family's error can reach Σ of the cells' errors (their
    misses disjoint) and no more: that sum, each cell's worst case over η computed exactly, is at most γ — and
    the same cells each at γ would break it."""
    gamma = 0.05
    each = split_gamma(gamma, len(thetas))
    assert each == gamma / len(thetas)
    errors = [worst_miss(clopper_pearson_n(theta, each), theta) for theta in thetas]
    assert all(e <= each for e in errors) and sum(errors) <= gamma
    unsplit = [worst_miss(clopper_pearson_n(theta, gamma), theta) for theta in thetas]
    assert sum(unsplit) > gamma


def test_split_gamma_refuses_a_bad_family():
    with pytest.raises(ValueError, match="parts must be an integer >= 1"):
        split_gamma(0.05, 0)
    with pytest.raises(ValueError, match="gamma must be in"):
        split_gamma(1.5, 3)
