"""Sequential test of a Bernoulli rate η against a threshold δ, with exact error.

Draws come in looks (cumulative counts ``looks``, the last one the cap). At a look with k successes
in n draws the test says "above" when P(Bin(n, δ − θ) ≥ k) ≤ ``above_level`` (that many successes
are implausible if η sat at the lower edge of the indifference zone), "below" when
P(Bin(n, δ + θ) ≤ k) ≤ ``below_level``, and otherwise draws on; where both hold, the smaller tail
relative to its level decides. At the cap a *forced* test decides by the point estimate, k/n ≥ δ
(as the fixed-n controller does); an unforced one stays undecided (None).

Guarantee, for every η: P(above | η ≤ δ − θ) ≤ γ and P(below | η ≥ δ + θ) ≤ γ; for |η − δ| < θ
either answer is acceptable. With θ = 0 (unforced only: a forced answer at η = δ cannot be right
with probability 1 − γ both ways) this is P(certify above | η < δ) ≤ γ and P(certify below | η ≥ δ)
≤ γ, undecided being the price. A θ > 0 on an unforced test lets it stop sooner, and then "above"
only certifies η > δ − θ (and "below" η < δ + θ). The edges are clipped to [0, 1]: where δ + θ ≥ 1
(δ − θ ≤ 0) that side's guarantee is empty and its boundary answers at the first contrary draw.

Both regions are monotone in k, so coupling the draws of two rates shows that P(above | η) rises and
P(below | η) falls with η: the worst cases are the edges, where the errors are computed exactly
(dynamic programming over the stopping rule, :mod:`uqdrive.uq.stopping`), and raising one level
only grows its own region. Calibration: the largest common level found with both errors ≤ γ, then
each level raised by bisection (exact, by that monotonicity) as far as its own error allows.
The level is the same at every look: front-loading it was measured while choosing (δ = 0.7, θ = γ = 0.05,
cap 738, a look every 4; not kept as code): a level shrinking like 1/√n keeps E[n] at η = 1 at 12,
cuts it at η = 0.9 from 24.7 to 21.9 and raises it at η = δ from 180 to 213; like 1/n, to 350.
Built once per parameter set and process, :meth:`ThresholdTest.decide` is a table lookup.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Literal

import numpy as np
from scipy import stats

from uqdrive.uq.bounds import check_unit
from uqdrive.uq.estimators import Draw
from uqdrive.uq.stopping import StopPoints, stop_points

Side = Literal["above", "below"]
"""``draw(m)`` returns m independent 0/1 outcomes; it may run them in parallel."""

_ABOVE, _BELOW = 1, -1  # decision codes in the stop points' labels (0: undecided)
_MAX_LEVEL = 4.0  # nominal levels searched in [γ/256, 4]: discreteness can let a tail level above γ be valid
_STEPS = 13  # bisection steps for the common level: to within 0.2 %
_RAISE_STEPS = 8  # bisection steps raising one level within [common, 2 common]: to within 0.3 %


@dataclass(frozen=True)
class ThresholdDecision:
    """The outcome of one run: ``decision`` (None: undecided at the cap), after ``n`` draws with ``k`` successes."""

    decision: Side | None
    n: int
    k: int


def doubling_looks(first: int, cap: int) -> tuple[int, ...]:
    """Cumulative draw counts first, 2·first, 4·first, … ending at ``cap``, e.g. (8, 16, …, 512, 738)."""
    if int(first) != first or not 1 <= first <= cap:
        raise ValueError(f"first must be an integer in [1, cap={cap}], got {first!r}")
    looks = [int(first)]
    while 2 * looks[-1] < cap:
        looks.append(2 * looks[-1])
    return (*looks, int(cap)) if looks[-1] != cap else tuple(looks)


@dataclass(frozen=True)
class _Boundaries:
    """Per look: the smallest count deciding "above" and the largest deciding "below"."""

    above_level: float
    below_level: float
    above_from: np.ndarray
    below_to: np.ndarray


@dataclass(frozen=True)
class _Tails:
    """[look, k]: P(Bin(n, δ − θ) ≥ k) (0 past n) and P(Bin(n, δ + θ) ≤ k) (+inf past n)."""

    above: np.ndarray
    below: np.ndarray


def _tails(test: ThresholdTest) -> _Tails:
    looks = np.array(test.looks)[:, None]
    k = np.arange(test.looks[-1] + 1)[None, :]
    inside = k <= looks
    above = np.where(inside, stats.binom.sf(k - 1, looks, test.low_edge), 0.0)
    below = np.where(inside, stats.binom.cdf(k, looks, test.high_edge), np.inf)
    return _Tails(above, below)


def _boundaries(test: ThresholdTest, tails: _Tails, above_level: float, below_level: float) -> _Boundaries:
    """The regions at these levels: "above" where P(Bin(n, δ − θ) ≥ k) ≤ above_level, "below" where
    P(Bin(n, δ + θ) ≤ k) ≤ below_level; where both hold, the smaller tail relative to its level wins;
    at the cap of a forced test every count decides, by k/n ≥ δ where neither tail does."""
    above_from = (tails.above > above_level).sum(1)  # the tail falls with k: counts below the boundary
    below_to = (tails.below <= below_level).sum(1) - 1
    for j in np.flatnonzero(above_from <= below_to):
        k = np.arange(above_from[j], below_to[j] + 1)
        split = k[tails.above[j, k] * below_level <= tails.below[j, k] * above_level]
        above_from[j] = split[0] if split.size else below_to[j] + 1
        below_to[j] = above_from[j] - 1
    if test.forced:
        n = test.looks[-1]
        estimate_above = int(np.flatnonzero(np.arange(n + 1) / n >= test.threshold)[0])
        above_from[-1] = min(above_from[-1], max(below_to[-1] + 1, estimate_above))
        below_to[-1] = above_from[-1] - 1
    return _Boundaries(above_level, below_level, above_from, below_to)


def _stop_points(test: ThresholdTest, bounds: _Boundaries) -> StopPoints:
    index = {n: j for j, n in enumerate(test.looks)}

    def rule(n: int, counts: np.ndarray) -> tuple[np.ndarray, ...]:
        j = index[n]
        code = np.where(counts >= bounds.above_from[j], _ABOVE, np.where(counts <= bounds.below_to[j], _BELOW, 0))
        return (code != 0) | (j == len(test.looks) - 1), code

    return stop_points(test.looks, rule)


def _errors(test: ThresholdTest, bounds: _Boundaries) -> tuple[float, float]:
    """Exact (P(above | η = low edge), P(below | η = high edge)): the worst cases of the two errors."""
    points = _stop_points(test, bounds)
    (code,) = points.labels
    above = points.mass([test.low_edge], lambda i, _: code[i, None] == _ABOVE)[0]
    below = points.mass([test.high_edge], lambda i, _: code[i, None] == _BELOW)[0]
    return float(above), float(below)


def _largest(valid: Callable[[float], bool], low: float, high: float, steps: int) -> float:
    """Bisection on the log level: the largest level in [low, high] found valid (``low`` is)."""
    low, high = math.log(low), math.log(high)
    for _ in range(steps):
        mid = (low + high) / 2
        low, high = (mid, high) if valid(math.exp(mid)) else (low, mid)
    return math.exp(low)


@lru_cache(maxsize=64)
def _calibrated(test: ThresholdTest) -> _Boundaries:
    """A common level for both boundaries (largest found with both errors ≤ γ), then each level raised
    as far as its own error allows — exact, since raising one level only grows its own region."""
    tails = _tails(test)

    def errors(above_level: float, below_level: float) -> tuple[float, float]:
        return _errors(test, _boundaries(test, tails, above_level, below_level))

    lowest = test.gamma / 256
    if max(errors(lowest, lowest)) > test.gamma:
        raise ValueError(
            f"no test with error <= gamma={test.gamma} at threshold={test.threshold} +- theta={test.theta} "
            f"within {test.looks[-1]} draws: the cap is too small"
        )
    common = _largest(lambda level: max(errors(level, level)) <= test.gamma, lowest, _MAX_LEVEL, _STEPS)
    above = _largest(lambda level: errors(level, common)[0] <= test.gamma, common, 2 * common, _RAISE_STEPS)
    below = _largest(lambda level: errors(above, level)[1] <= test.gamma, common, 2 * common, _RAISE_STEPS)
    return _boundaries(test, tails, above, below)


@dataclass(frozen=True)
class ThresholdTest:
    """Sequential test of "η ≥ ``threshold``?" with exact per-decision error ≤ ``gamma`` (see the module).

    ``looks``: increasing cumulative draw counts, the last one the cap. ``theta``: half-width of the
    indifference zone (> 0 when ``forced``). ``forced``: decide by k/n ≥ threshold at the cap (a
    controller) or stay undecided there (a certifier). Calibrated on construction (once per
    parameter set and process); a bad parameter raises ``ValueError`` naming it.
    """

    threshold: float
    gamma: float
    looks: tuple[int, ...]
    theta: float = 0.0
    forced: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "threshold", check_unit("threshold", self.threshold))
        object.__setattr__(self, "gamma", check_unit("gamma", self.gamma))
        looks = tuple(int(n) for n in self.looks)
        if not looks or looks[0] < 1 or any(b <= a for a, b in zip(looks, looks[1:])) or looks != tuple(self.looks):
            raise ValueError(f"looks must be increasing integer draw counts >= 1, got {self.looks!r}")
        object.__setattr__(self, "looks", looks)
        if not 0 <= self.theta < 1:
            raise ValueError(f"theta must be in [0, 1), got {self.theta!r}")
        object.__setattr__(self, "theta", float(self.theta))
        if self.forced and self.theta == 0:
            raise ValueError("a forced test needs theta > 0: at eta = threshold one of its two answers is wrong")
        object.__setattr__(self, "_index", {n: j for j, n in enumerate(looks)})
        object.__setattr__(self, "_bounds", _calibrated(self))

    @property
    def low_edge(self) -> float:
        """max(δ − θ, 0): at and below it, "above" is an error."""
        return max(self.threshold - self.theta, 0.0)

    @property
    def high_edge(self) -> float:
        """min(δ + θ, 1): at and above it, "below" is an error."""
        return min(self.threshold + self.theta, 1.0)

    @property
    def above_level(self) -> float:
        """Calibrated level of the "above" boundary's tail P(Bin(n, δ − θ) ≥ k)."""
        return self._bounds.above_level

    @property
    def below_level(self) -> float:
        """Calibrated level of the "below" boundary's tail P(Bin(n, δ + θ) ≤ k)."""
        return self._bounds.below_level

    def decide(self, k: int, n: int) -> Side | None:
        """The decision after n draws (a look) with k successes; None: draw on (or, at the cap of an
        unforced test, undecided)."""
        j = self._index.get(n)
        if j is None or not 0 <= k <= n:
            raise ValueError(f"decide needs n in looks {self.looks} and 0 <= k <= n, got k={k!r}, n={n!r}")
        if k >= self._bounds.above_from[j]:
            return "above"
        if k <= self._bounds.below_to[j]:
            return "below"
        return None

    def run(self, draw: Draw) -> ThresholdDecision:
        """Draw look by look (``draw(m)`` once per look, m the look's new draws) until a decision or the cap."""
        k, n = 0, 0
        for look in self.looks:
            batch = np.asarray(draw(look - n)).reshape(-1)
            if batch.shape[0] != look - n or not np.isin(batch, (0, 1)).all():
                raise ValueError(f"draw({look - n}) must return {look - n} outcomes in {{0, 1}}")
            k, n = k + int(batch.sum()), look
            decision = self.decide(k, n)
            if decision is not None:
                return ThresholdDecision(decision, n, k)
        return ThresholdDecision(None, n, k)

    @cached_property
    def stop_points(self) -> StopPoints:
        """The reachable stops, labelled with the decision code (+1 above, −1 below, 0 undecided)."""
        return _stop_points(self, self._bounds)

    def operating_characteristics(self, etas: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact (P(above), P(below), E[draws]) at each true rate; P(undecided) is the rest."""
        etas = np.atleast_1d(np.asarray(etas, dtype=float))
        (code,) = self.stop_points.labels
        above, below = self.stop_points.masses(
            etas, [lambda i, _: code[i, None] == _ABOVE, lambda i, _: code[i, None] == _BELOW]
        )
        return above, below, self.stop_points.expected_draws(etas)

    def worst_errors(self) -> tuple[float, float]:
        """Exact (P(above | η = low_edge), P(below | η = high_edge)): the largest the two errors get."""
        return _errors(self, self._bounds)
