"""The runs needed and the mean interval's tuning, checked by code independent of `uqdrive.uq.betting`.

- Runs needed (`uq.runs_needed`) at small sizes (level 0.05, gains large enough that R stays under 100): at the R
  it reports, a fresh simulation of the decision written here (a plain loop over the runs, WSR's fixed-R stakes,
  cap 0.99) decides with probability ≥ 0.8 within Monte Carlo error, and at well under that R it does not.
- The interval's ends agree with a grid search over candidate means written here (confseq does not build on this
  machine: it needs Boost), and no interval valid for every spread can be narrower than the floor
  1 − (level/2)^(1/R) on all-zero runs (a run at −1 with that probability is missed by all R draws with probability
  level/2); ours is within 0.03 of it at R = 10, 30, 100.
About 4 s of CPU."""

import math

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq.betting import mean_interval
from uqdrive.uq.claims import CAP, mean_verdicts
from uqdrive.uq.runs_needed import power, resampled, runs_needed, worst

LEVEL, MARGIN = 0.05, 0.1


def wealth(x: np.ndarray, m: float, above: bool, level: float) -> float:
    """log K⁺(m) or log K⁻(m) for runs x on [0, 1], written out run by run (WSR, fixed-R plug-in stakes)."""
    total, var, runs = 0.0, 0.25, len(x)
    for i, xi in enumerate(x, start=1):
        stake = math.sqrt(2 * math.log(2 / level) / (var * runs))
        stake = min(stake, CAP / m if above else CAP / (1 - m))
        total += math.log1p(stake * (xi - m) if above else -stake * (xi - m))
        # σ̂²_i = (¼ + Σ_{j ≤ i} (x_j − μ̂_{j−1})²) / (i + 1), μ̂_j = (½ + Σ_{k ≤ j} x_k) / (j + 1)
        var = (0.25 + sum((x[j] - (0.5 + x[:j].sum()) / (j + 1)) ** 2 for j in range(i))) / (i + 1)
    return total


def decided_here(diffs: np.ndarray, level: float, margin: float) -> bool:
    x, threshold = (np.asarray(diffs) + 1) / 2, math.log(2 / level)
    zero, low, high = 0.5, (1 - margin) / 2, (1 + margin) / 2
    if wealth(x, zero, True, level) >= threshold or wealth(x, zero, False, level) >= threshold:
        return True
    return wealth(x, low, True, level) >= threshold and wealth(x, high, False, level) >= threshold


def test_the_decision_written_here_is_the_procedures():
    rng = np.random.default_rng(3)
    for _ in range(300):
        runs = int(rng.integers(2, 30))
        diffs = rng.choice([-1.0, -0.2, 0.0, 0.05, 0.3, 1.0], runs) if rng.random() < 0.5 else rng.uniform(-1, 1, runs)
        ours = bool(mean_verdicts(diffs[None], LEVEL, MARGIN)[0] > 0)
        assert ours == decided_here(diffs, LEVEL, MARGIN), diffs


SPREADS = {
    "study-like: piled at 0 with outright gains": resampled(np.array([0.0, 0.0, 0.6, 0.5, 0.0, 0.7, 0.4, 0.0])),
    "worst: ±1 with mean 0.6": worst(0.6),
}


@pytest.mark.parametrize("spread", list(SPREADS))
def test_the_runs_needed_reach_the_power_in_a_fresh_simulation(spread):
    sampler = SPREADS[spread]

    def decided(x: np.ndarray) -> np.ndarray:
        return mean_verdicts(x, LEVEL, MARGIN) > 0

    needed = runs_needed(decided, sampler, sims=400)
    assert needed is not None and 4 <= needed <= 100
    rng, sims = np.random.default_rng(12345), 600

    def fresh(runs: int) -> int:
        return sum(decided_here(sampler(rng, (1, runs))[0], LEVEL, MARGIN) for _ in range(sims))

    hits = fresh(needed)
    assert stats.beta.ppf(0.999, hits + 1, sims - hits) >= 0.8, (needed, hits / sims)  # reaches 0.8 within MC error
    fewer = max(2, int(needed * 0.6))
    misses = fresh(fewer)
    assert stats.beta.ppf(0.001, misses, sims - misses + 1) < 0.8, (fewer, misses / sims)
    assert power(decided, sampler, needed, 400) >= 0.8


def interval_here(diffs: np.ndarray, level: float, grid: int = 2001) -> tuple[float, float]:
    """The interval as the set of candidate means on a grid that neither side's wealth rejects."""
    x, threshold = (np.asarray(diffs) + 1) / 2, math.log(2 / level)
    kept = [
        m
        for m in np.linspace(1e-6, 1 - 1e-6, grid)
        if wealth(x, m, True, level) < threshold and wealth(x, m, False, level) < threshold
    ]
    return 2 * min(kept) - 1, 2 * max(kept) - 1


def test_the_interval_is_a_grid_searchs_written_here():
    rng = np.random.default_rng(8)
    for diffs in (np.zeros(10), rng.choice([0.0, 0.1, 0.3, -0.2], 12), rng.uniform(-1, 1, 7)):
        ours = mean_interval(diffs, -1.0, 1.0, LEVEL, horizon=len(diffs), cap=CAP)
        low, high = interval_here(diffs, LEVEL, 801)
        assert ours.low == pytest.approx(low, abs=2.6e-3) and ours.high == pytest.approx(high, abs=2.6e-3)


@pytest.mark.parametrize("runs", [10, 30, 100])
def test_no_valid_interval_beats_the_floor_and_ours_is_near_it(runs):
    level = 0.0025
    floor = 1 - (level / 2) ** (1 / runs)
    # the floor binds: with a run at −1 of probability p just above the floor the all-zero sample is drawn more
    # often than level/2, so an interval excluding −p there would miss more often than its guarantee allows
    assert (1 - floor * 1.001) ** runs < level / 2 < (1 - floor * 0.999) ** runs
    ours = mean_interval(np.zeros(runs), -1.0, 1.0, level, horizon=runs, cap=CAP)
    assert -floor - 0.03 < ours.low <= -floor and floor <= ours.high < floor + 0.03
