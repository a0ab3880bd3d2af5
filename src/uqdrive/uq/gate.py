"""What a certification gate proves, said and checked: the interval matched to its sequential test, the budget
floor, the operating characteristic near the target, and the error spent across repeated attempts.

**The interval.** The test (`uqdrive.uq.threshold.ThresholdTest`, unforced) stops at a look (n, k) with a code:
above (certified), below (refuted) or undecided at the cap. Its stop points are ordered stagewise — refuted at an
earlier look lowest, then refuted later, undecided at the cap by k, certified at the cap, …, certified at the first
look highest; within a look by k — and the ends are the exact inversion of that ordering at the stopping time:

    low(t)  = inf {p : P_p(T ⪰ t) > γ},     high(t) = sup {p : P_p(T ⪯ t) > γ}.

Raising η1 only moves a run up the ordering (couple the draws: more successes stop it "above" sooner, or "below"
later or not at all), so P_p(T ⪰ t) rises with p and the bisections find these ends; whatever the true η1,
P(low > η1) ≤ γ and P(high < η1) ≤ γ at the stopping time, exactly (each end alone; both together 1 − 2γ).
Every certified stop ranks above every other, so P_p(T ⪰ t) ≤ P_p(certified) ≤ γ for p ≤ η − θ: a certified
run's low is ≥ η − θ. A run that did not certify gets low capped just below η − θ (by ``MARGIN``: only lowers it,
so the guarantee stands), and likewise high for refutation: **low ≥ η − θ exactly when certified, high ≤ η + θ
exactly when refuted**; the printed interval never contradicts the verdict.

**The floor.** A test that certifies after n safe rollouts of n certifies a policy at η1 = η − θ with probability
≥ (η − θ)^n, so no valid test certifies within fewer than ⌈ln γ / ln(η − θ)⌉ rollouts; a budget below that is
refused before any rollout, with the budget this test's looks would need (`budget_floor`).

**Attempts.** Attempt k of a policy name spends γ_k = 6γ / (π² k²) (Σ γ_k = γ) on fresh seeds: whatever is
resubmitted, P(some attempt ever certifies a policy whose η1 ≤ η − θ) ≤ Σ γ_k ≤ γ (union bound; each attempt's
error is ≤ γ_k given all that came before, its seeds unused by any earlier attempt).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the floor and γ_k need no scipy: a refused input stays fast
    from uqdrive.uq.threshold import ThresholdTest

MARGIN = 1e-6  # how far below η − θ (above η + θ) an undecided end is capped: visible at 3 decimals
_BISECT = 48  # bisection steps for an end: to within 4e-15
CODES = {"above": 1, "below": -1, None: 0}


def attempt_gamma(gamma: float, attempt: int) -> float:
    """γ_k = 6γ / (π² k²): the error attempt k (1, 2, …) of one policy name may spend; the sum over k is γ."""
    if int(attempt) != attempt or attempt < 1:
        raise ValueError(f"attempt must be an integer >= 1, got {attempt!r}")
    return 6 * gamma / (math.pi**2 * attempt**2)


def zero_failure_floor(eta: float, theta: float, gamma: float) -> int:
    """⌈ln γ / ln(η − θ)⌉: fewer rollouts than this, all of them safe, cannot certify η1 ≥ η − θ at error γ."""
    return math.ceil(math.log(gamma) / math.log(eta - theta))


def looks_for(look_size: int, budget: int) -> tuple[int, ...]:
    """A look every ``look_size`` rollouts, and one at the budget."""
    return tuple(sorted({*range(look_size, budget + 1, look_size), budget}))


def certifies_all_safe(test: ThresholdTest) -> bool:
    """Does the test certify a policy none of whose rollouts failed, within its budget?"""
    return test.decide(test.looks[-1], test.looks[-1]) == "above"


def budget_floor(eta: float, theta: float, gamma: float, look_size: int) -> int:
    """A budget (a multiple of ``look_size``) whose test certifies a policy with no failure: from the zero-failure
    floor up, each try the larger of 5 % more and the n at which (η − θ)^n reaches the last try's calibrated level
    (the all-safe run's tail), so a few calibrations find it; within 5 % of the smallest such budget."""
    from uqdrive.uq.threshold import ThresholdTest

    budget = look_size * math.ceil(zero_failure_floor(eta, theta, gamma) / look_size)
    while True:
        test = ThresholdTest(eta, gamma, looks_for(look_size, budget), theta=theta, forced=False)
        if certifies_all_safe(test):
            return budget
        reach = math.log(min(test.above_level, 1.0)) / math.log(eta - theta)
        budget = look_size * math.ceil(max(1.05 * budget, reach) / look_size)


def _rank(test: ThresholdTest, n: np.ndarray, k: np.ndarray, code: np.ndarray) -> np.ndarray:
    """The stagewise rank of stops (n, k, code) (a larger rank: more evidence that η1 is high)."""
    last, look = len(test.looks), np.searchsorted(test.looks, n)
    stage = np.where(code > 0, 2 * last - look, np.where(code < 0, look, last))  # undecided: between the two
    return stage * (test.looks[-1] + 1) + k


def _tail(test: ThresholdTest, select: np.ndarray, p: float) -> float:
    return float(test.stop_points.mass(np.array([p]), lambda i, _: select[i, None])[0])


def _bisect(test: ThresholdTest, select: np.ndarray, rising: bool) -> float:
    """inf {p : tail > γ} (``rising``) or sup {p : tail > γ} (falling) of P_p(select)."""
    lo, hi = 0.0, 1.0
    for _ in range(_BISECT):
        mid = (lo + hi) / 2
        above = _tail(test, select, mid) > test.gamma
        lo, hi = (lo, mid) if above == rising else (mid, hi)
    return lo if rising else hi


@dataclass(frozen=True)
class GateInterval:
    """η1 ≥ ``low`` and η1 ≤ ``high``, each with confidence 1 − γ at the stopping time (see the module)."""

    low: float
    high: float

    def shown(self) -> str:
        """``[low, high]`` at 3 decimals, low rounded down and high up (the rounding never narrows it)."""
        low, high = math.floor(self.low * 1000 + 1e-9) / 1000, math.ceil(self.high * 1000 - 1e-9) / 1000
        return f"[{low:.3f}, {high:.3f}]"


def stop_interval(test: ThresholdTest, k: int, n: int) -> GateInterval:
    """The interval at the stop (n, k) of ``test`` (a look where it stopped: decided, or the cap)."""
    code = CODES[test.decide(k, n)]
    if code == 0 and n != test.looks[-1]:
        raise ValueError(f"the test does not stop at k={k}, n={n}: neither decided nor the cap")
    points = test.stop_points
    ranks, at = _rank(test, points.n, points.k, points.labels[0]), _rank(test, n, k, code)
    low = _bisect(test, ranks >= at, rising=True)
    high = _bisect(test, ranks <= at, rising=False)
    if code != 1:
        low = min(low, test.low_edge - MARGIN)
    if code != -1:
        high = max(high, min(test.high_edge + MARGIN, 1.0))
    return GateInterval(max(low, 0.0), min(high, 1.0))


@dataclass(frozen=True)
class NearTarget:
    """The operating characteristic near η1 = η: P(certified) and P(undecided) at η1 = η, and the band of true η1
    (on a grid of step 0.001) where the right verdict — certified for η1 ≥ η + θ … — has probability < 1 − γ."""

    certify_at_eta: float
    undecided_at_eta: float
    band: tuple[float, float]
    gamma: float

    def said(self) -> str:
        low, high = self.band
        return (
            f"at eta1 = eta it certifies with probability {self.certify_at_eta:.2f} and ends undecided with "
            f"{self.undecided_at_eta:.2f}; for eta1 in ({low:.3f}, {high:.3f}) the right verdict has probability "
            f"below 1 - {self.gamma:.3g}"
        )


def near_target(test: ThresholdTest) -> NearTarget:
    """Exact P(certified), P(refuted) on a grid: the right verdict is "certified" for η1 ≥ η, "refuted" below."""
    grid = np.round(np.arange(0, 1001) / 1000, 3)
    above, below, _ = test.operating_characteristics(grid)
    right = np.where(grid >= test.threshold, above, below)
    short = grid[right < 1 - test.gamma]
    at = test.operating_characteristics(test.threshold)
    band = (float(short.min()) - 0.001, float(short.max()) + 0.001) if short.size else (test.threshold,) * 2
    return NearTarget(float(at[0][0]), float(1 - at[0][0] - at[1][0]), band, test.gamma)
