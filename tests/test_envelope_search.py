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


def test_rate_spread_and_straddle_are_those_of_kernel_weighted_counts():
    rng = np.random.default_rng(1)
    points, outcomes = rng.random((30, 2)), rng.integers(0, 2, 30)
    model = BoundaryModel(points, outcomes, TAU, bandwidth=0.2)
    for row in rng.random((7, 2)):
        w = np.exp(-np.sum((points - row) ** 2, axis=1) / (2 * 0.2**2))
        rate = w @ outcomes / w.sum()
        spread = stats.beta(1 + w @ outcomes, 1 + w @ (1 - outcomes)).std()
        assert model.rate(row[None])[0] == pytest.approx(rate, rel=1e-12)
        assert model.spread(row[None])[0] == pytest.approx(spread, rel=1e-10)
        assert model.straddle(row[None])[0] == pytest.approx(1 + spread - abs(rate - TAU), rel=1e-10)


def run_truth(rng: np.random.Generator):
    calls = []

    def run(points: np.ndarray) -> np.ndarray:
        calls.append(len(points))
        return (rng.random(len(points)) < diagonal_truth(points)).astype(int)

    return run, calls


def test_search_spends_its_budget_in_rounds_and_sends_the_rounds_to_the_boundary():
    near = []
    for seed in range(4):
        run, calls = run_truth(np.random.default_rng(seed))
        result = search(run, 2, TAU, SearchSettings(budget=80, initial=16, batch=8, bandwidth=0.1, seed=seed))
        assert calls == [16, 8, 8, 8, 8, 8, 8, 8, 8] and result.rounds == tuple(calls)
        assert len(np.unique(result.points, axis=0)) == 80
        near.append(np.mean(np.abs(result.points[16:].sum(1) - BOUNDARY) / np.sqrt(2) < 0.1))
    uniform = np.mean(np.abs(candidates(2, 0).sum(1) - BOUNDARY) / np.sqrt(2) < 0.1)  # 19 % of the box
    assert np.mean(near) > 2.5 * uniform, (near, uniform)


def test_the_last_round_is_cut_to_the_budget_and_settings_are_checked():
    run, calls = run_truth(np.random.default_rng(0))
    search(run, 3, TAU, SearchSettings(budget=21, initial=8, batch=5))
    assert calls == [8, 5, 5, 3]
    with pytest.raises(ConfigError, match=r"^search.initial=40 must be <= budget \(32\)$"):
        validate(SearchSettings, {"budget": 32, "initial": 40}, "search")
