"""Holm's adjusted p-values on hand-computed sets, the levels Holm grants against a step-down written here, and the
Bonferroni split of γ over a family of cells with each fixed-n Clopper–Pearson cell's error computed exactly
(binomial sums at every jump of the error, here)."""

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq import clopper_pearson_n
from uqdrive.uq.multiplicity import holm, holm_levels, split_gamma


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


def step_down(p: list[float], alpha: float) -> tuple[list[bool], list[float]]:
    """Holm's procedure as its definition reads: walk the sorted p-values (ties in input order), reject while
    p_(j) ≤ α / (m − j + 1); every hypothesis from the first failure on keeps that failure's level."""
    m, order = len(p), sorted(range(len(p)), key=lambda i: (p[i], i))
    rejected, levels, failed_at = [False] * m, [0.0] * m, None
    for j, i in enumerate(order):
        level = alpha / (m - j) if failed_at is None else alpha / (m - failed_at)
        if failed_at is None and p[i] <= level:
            rejected[i] = True
        elif failed_at is None:
            failed_at = j
        levels[i] = level
    return rejected, levels


def families() -> list[list[float]]:
    """Random families, families with ties (p-values on a coarse grid), and families whose p-values sit exactly on
    Holm's levels α / k (rejected: ≤)."""
    rng = np.random.default_rng(5)
    out = [list(rng.random(m) ** 4) for m in (1, 2, 3, 5, 8, 20) for _ in range(30)]
    out += [list(np.round(rng.random(m) * 0.05, 2)) for m in (2, 4, 6) for _ in range(30)]
    out += [[0.05 / 4, 0.05 / 3, 0.05 / 2, 0.05], [0.05 / 4, 0.05 / 4, 0.05 / 2, 0.3], [0.05 / 3, 0.05 / 2, 0.9]]
    return out


def test_holm_levels_reproduce_holms_decisions():
    for p in families():
        rejected, levels = step_down(p, 0.05)
        granted = holm_levels(p, 0.05)
        assert list(granted) == levels and [q <= g for q, g in zip(p, granted)] == rejected, p
        if not set(p) & {0.05 / k for k in range(1, 5)}:  # off the boundary, where (m − j + 1) p cannot round over α
            assert [a <= 0.05 for a in holm(p)] == rejected, p
    # on the levels exactly: 0.0125 ≤ 0.05/4, 0.05/3 ≤ 0.05/3, …: every one rejected
    on_levels = np.array([0.05 / 4, 0.05 / 3, 0.05 / 2, 0.05])
    assert (on_levels <= holm_levels(on_levels, 0.05)).all()
    with pytest.raises(ValueError, match="non-empty 1-d sequence"):
        holm_levels([], 0.05)


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
