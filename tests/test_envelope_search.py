"""Phase one of an envelope: the kernel-smoothed posterior, and rounds of rollouts that go to the boundary."""

import numpy as np
import pytest
from scipy import stats

from uqdrive.envelope.search import BoundaryModel, SearchSettings, candidates, search
from uqdrive.schema import ConfigError, validate

TAU = 0.9


def diagonal_truth(points: np.ndarray) -> np.ndarray:
    """η1 falls from 1 to 0 across the anti-diagonal; η1 = τ on the line u0 + u1 = 0.8 + 0.05·ln(1/9)."""
    return 1 / (1 + np.exp((points[:, 0] + points[:, 1] - 0.8) / 0.05))


BOUNDARY = 0.8 + 0.05 * np.log(1 / 9)


def test_the_posterior_is_the_beta_of_kernel_weighted_counts():
    rng = np.random.default_rng(1)
    points, outcomes = rng.random((30, 2)), rng.integers(0, 2, 30)
    model = BoundaryModel(points, outcomes, TAU, bandwidth=0.2)
    x = rng.random((7, 2))
    for row in x:
        w = np.exp(-np.sum((points - row) ** 2, axis=1) / (2 * 0.2**2))
        a, b = 1 + w @ outcomes, 1 + w @ (1 - outcomes)
        assert model.p_safe(row[None])[0] == pytest.approx(stats.beta.sf(TAU, a, b), rel=1e-10)
        assert model.mean(row[None])[0] == pytest.approx(a / (a + b), rel=1e-12)


def run_truth(rng: np.random.Generator):
    calls = []

    def run(points: np.ndarray) -> np.ndarray:
        calls.append(len(points))
        return (rng.random(len(points)) < diagonal_truth(points)).astype(int)

    return run, calls


def test_search_spends_its_budget_in_rounds_and_sends_the_rounds_to_the_boundary():
    settings = SearchSettings(budget=80, initial=16, batch=8, bandwidth=0.15)
    run, calls = run_truth(np.random.default_rng(7))
    result = search(run, 2, TAU, settings)
    assert calls == [16, 8, 8, 8, 8, 8, 8, 8, 8] and result.rounds == tuple(calls)
    assert len(np.unique(result.points, axis=0)) == 80
    distance = np.abs(result.points.sum(1) - BOUNDARY) / np.sqrt(2)
    uniform = np.abs(candidates(2, 0).sum(1) - BOUNDARY) / np.sqrt(2)
    near, near_uniform = np.mean(distance[16:] < 0.1), np.mean(uniform < 0.1)
    assert near > 2 * near_uniform, (near, near_uniform)  # uniform sampling puts ~27 % within 0.1 of the line


def test_the_last_round_is_cut_to_the_budget_and_settings_are_checked():
    run, calls = run_truth(np.random.default_rng(0))
    search(run, 3, TAU, SearchSettings(budget=21, initial=8, batch=5))
    assert calls == [8, 5, 5, 3]
    with pytest.raises(ConfigError, match=r"^search.initial=40 must be <= budget \(32\)$"):
        validate(SearchSettings, {"budget": 32, "initial": 40}, "search")
