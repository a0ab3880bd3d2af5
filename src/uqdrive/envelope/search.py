"""Phase one of an envelope: spend a budget of rollouts finding where the controller fails, most of them near
the boundary η1(x) = τ between the conditions it drives safely enough and the ones it does not.

Why this sampler: a falsification sampler (cross-entropy, simulated annealing, Bayesian optimisation of a
robustness score) looks for the worst condition and spends its rollouts there; what the map needs is the level
set η1 = τ, wherever it runs. So phase one is active level-set estimation (the "straddle" idea of Bryan et al.,
NIPS 2005): a space-filling start (scrambled Sobol points), then rounds of rollouts where the kernel-smoothed
rate of safe runs is near τ and still uncertain (their straddle score). It assumes nothing about the shape of
η1 (no monotone direction, which a ring radius need not have), costs microseconds per round, and a round's
rollouts run in parallel. Its data choose the partition that phase two certifies on fresh seeds; no guarantee
rests on it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from uqdrive.schema import Count, Positive, Seed, invalid, schema

CANDIDATES_LOG2 = 10  # 1024 scrambled Sobol points: where each round's conditions are chosen from


@schema(frozen=True)
class SearchSettings:
    """Phase one's budget: ``budget`` rollouts, the first ``initial`` spread over the box (Sobol), then rounds
    of ``batch`` (run in parallel) where η1 is near τ and least certain; ``bandwidth``: the kernel's width in
    the unit cube (how far one rollout informs the estimate)."""

    budget: Count = 64
    initial: Count = 16
    batch: Count = 8
    bandwidth: Positive = 0.1
    seed: Seed = 0  # the Sobol candidates' scrambling

    def __post_init__(self) -> None:
        if self.initial > self.budget:
            raise invalid("initial", self.initial, f"must be <= budget ({self.budget})")


class BoundaryModel:
    """What phase one's rollouts say about η1(x): each outcome y_i counts at x with the weight
    w_i = exp(−|x − x_i|² / 2h²), which falls with distance. ``rate`` (the weighted safe fraction) says where η1
    crosses τ; the Beta(1 + Σ w_i y_i, 1 + Σ w_i (1 − y_i)) posterior's spread says how sure that is."""

    def __init__(self, points: np.ndarray, outcomes: np.ndarray, threshold: float, bandwidth: float):
        self.points = np.asarray(points, dtype=float).reshape(len(outcomes), -1)
        self.outcomes = np.asarray(outcomes, dtype=float)
        self.threshold, self.bandwidth = float(threshold), float(bandwidth)

    def counts(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Kernel-weighted (safe, unsafe) counts at each row of ``x``."""
        w = kernel(np.atleast_2d(np.asarray(x, dtype=float)), self.points, self.bandwidth)
        safe = w @ self.outcomes
        return safe, w.sum(1) - safe

    def rate(self, x: np.ndarray) -> np.ndarray:
        """The kernel-weighted safe fraction (Nadaraya–Watson): where the boundary runs. (A posterior mean would
        pull a sparsely sampled, always safe corner below a τ near 1.)"""
        return _rate(*self.counts(x))

    def spread(self, x: np.ndarray) -> np.ndarray:
        """The posterior's standard deviation: large where few rollouts are near, or where they disagree."""
        return _spread(*self.counts(x))

    def straddle(self, x: np.ndarray) -> np.ndarray:
        """Bryan et al.'s straddle score, spread − |rate − τ| (shifted by 1 to stay positive): high where η1 is
        near τ and still uncertain. It prefers the boundary to a well-sampled safe plateau, where a Beta
        probability P(η1 ≥ τ) would stay undecided for tens of rollouts when τ is near 1."""
        return _straddle(*self.counts(x), self.threshold)


def kernel(x: np.ndarray, points: np.ndarray, bandwidth: float) -> np.ndarray:
    """[row of x, point] weights exp(−|x − point|² / 2h²)."""
    d2 = ((x[:, None, :] - points[None, :, :]) ** 2).sum(-1)
    return np.exp(d2 / (-2 * bandwidth**2))


def _rate(safe: np.ndarray, unsafe: np.ndarray) -> np.ndarray:
    total = safe + unsafe
    return np.divide(safe, total, out=np.full_like(total, 0.5), where=total > 0)


def _spread(safe: np.ndarray, unsafe: np.ndarray) -> np.ndarray:
    a, b = 1 + safe, 1 + unsafe
    return np.sqrt(a * b / ((a + b) ** 2 * (a + b + 1)))


def _straddle(safe: np.ndarray, unsafe: np.ndarray, threshold: float) -> np.ndarray:
    return 1 + _spread(safe, unsafe) - np.abs(_rate(safe, unsafe) - threshold)


def candidates(dim: int, seed: int) -> np.ndarray:
    """The conditions phase one chooses from, in the unit cube: scrambled Sobol points (their prefixes are
    space-filling, which is what the first rollouts need)."""
    return qmc.Sobol(dim, scramble=True, rng=np.random.default_rng(seed)).random_base2(CANDIDATES_LOG2)


def pick_batch(model: BoundaryModel, pool: np.ndarray, available: np.ndarray, size: int) -> np.ndarray:
    """Indices into ``pool`` (among ``available``) of the ``size`` next conditions: greedily the highest straddle
    score, each pick then believed to come out at the current rate and its neighbourhood penalised (local
    penalisation), so one round's rollouts spread along the boundary instead of piling onto one point."""
    chosen: list[int] = []
    open_ = available.copy()
    safe, unsafe = model.counts(pool)
    penalty = np.ones(len(pool))
    for _ in range(min(size, int(open_.sum()))):
        score = np.where(open_, _straddle(safe, unsafe, model.threshold) * penalty, -1.0)
        j = int(np.argmax(score))
        chosen.append(j)
        open_[j] = False
        near = kernel(pool, pool[j : j + 1], model.bandwidth)[:, 0]
        believed = _rate(safe[j], unsafe[j])
        safe, unsafe = safe + near * believed, unsafe + near * (1 - believed)
        penalty *= 1 - near
    return np.array(chosen, dtype=int)


@dataclass(frozen=True)
class SearchResult:
    """Phase one's rollouts: conditions (unit cube), outcomes (1 = safe) in the order run, rounds' sizes."""

    points: np.ndarray
    outcomes: np.ndarray
    rounds: tuple[int, ...]

    def model(self, threshold: float, bandwidth: float) -> BoundaryModel:
        return BoundaryModel(self.points, self.outcomes, threshold, bandwidth)


def search(
    run: Callable[[np.ndarray], np.ndarray], dim: int, threshold: float, settings: SearchSettings
) -> SearchResult:
    """Phase one: ``run(points)`` drives one rollout at each condition (rows in the unit cube) and returns their
    outcomes (1 = safe); called once for the initial design and once per round, ``settings.budget`` in all."""
    pool = candidates(dim, settings.seed)
    available = np.ones(len(pool), dtype=bool)
    available[: settings.initial] = False
    points = pool[: settings.initial]
    outcomes = _outcomes(run(points), len(points))
    rounds = [len(points)]
    rounds_left = math.ceil((settings.budget - settings.initial) / settings.batch)
    for _ in range(rounds_left):
        size = min(settings.batch, settings.budget - len(outcomes))
        picked = pick_batch(BoundaryModel(points, outcomes, threshold, settings.bandwidth), pool, available, size)
        available[picked] = False
        points = np.vstack([points, pool[picked]])
        outcomes = np.concatenate([outcomes, _outcomes(run(pool[picked]), len(picked))])
        rounds.append(len(picked))
    return SearchResult(points, outcomes, tuple(rounds))


def _outcomes(values: np.ndarray, size: int) -> np.ndarray:
    out = np.asarray(values).reshape(-1)
    if out.shape[0] != size or not np.isin(out, (0, 1)).all():
        raise ValueError(f"run({size} conditions) must return {size} outcomes in {{0, 1}}, got {np.shape(values)}")
    return out.astype(np.int64)
