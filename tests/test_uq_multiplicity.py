"""Holm's adjusted p-values on hand-computed sets, and the Bonferroni split of γ over a family of cells with each
fixed-n Clopper–Pearson cell's error computed exactly (binomial sums at every jump of the error, here)."""

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq import clopper_pearson_n
from uqdrive.uq.multiplicity import holm, per_cell_gamma


def test_holm_on_a_hand_computed_set():
    # sorted: 0.005·4 = 0.02, 0.01·3 = 0.03, 0.03·2 = 0.06, 0.04·1 = 0.04 → running max 0.02, 0.03, 0.06, 0.06
    assert holm([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    # ties keep equal adjusted values: 0.001·4, 0.2·3, max(0.2·2, 0.6), max(0.5·1, 0.6)
    assert holm([0.5, 0.2, 0.2, 0.001]) == pytest.approx([0.6, 0.6, 0.6, 0.004])
    assert holm([0.4, 0.45, 0.6]) == pytest.approx([1.0, 1.0, 1.0])  # 0.4·3 capped at 1
    assert holm([0.04]) == pytest.approx([0.04])
    with pytest.raises(ValueError, match="p-values in \\[0, 1\\]"):
        holm([0.1, 1.5])


def test_holm_adjusted_p_values_are_monotone_in_the_raw_ones_and_never_below_them():
    raw = np.random.default_rng(3).random(40) ** 3
    adjusted = holm(raw)
    order = np.argsort(raw)
    assert (np.diff(adjusted[order]) >= 0).all() and (adjusted >= raw).all() and (adjusted <= 1).all()


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
    gamma = 0.05
    each = per_cell_gamma(gamma, len(thetas))
    assert each == gamma / len(thetas)
    errors = [worst_miss(clopper_pearson_n(theta, each), theta) for theta in thetas]
    assert all(e <= each for e in errors) and sum(errors) <= gamma


def test_per_cell_gamma_refuses_a_bad_family():
    with pytest.raises(ValueError, match="cells must be an integer >= 1"):
        per_cell_gamma(0.05, 0)
    with pytest.raises(ValueError, match="gamma must be in"):
        per_cell_gamma(1.5, 3)
