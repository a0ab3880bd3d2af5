"""The η2 tier of a frame — η2 ≥ δ1, δ2 ≤ η2 < δ1 or η2 < δ2 — decided from a stream of Bernoulli draws read at
fixed looks, with its exact error computed when the rule is built.

Each draw is 1 when a fresh weight sample's decision lies within ε of π(o) (rate η2). Two rules:

- `TierTest` (sequential draws): two forced `ThresholdTest`s at level γ/2, of δ1 and of δ2, share the draws and
  the looks (doubling from ``look`` to the cap); the frame stops at the first look that settles its tier: δ1's
  test says "above" (tier 0), δ2's says "below" (tier 2), or δ1's says "below" while δ2's says "above" (tier 1).
  At the cap both tests are forced (by the point estimate), so every frame ends with a tier. Inside this rule a
  test keeps running after its first answer and may later give the other one, which a test alone cannot: the
  tests' levels alone do not bound the rule's error, so it is computed.
- `FixedTier` (the paper's fixed draws): one look at the cap, the tier of the point estimate k/n.

Error: the tier is *wrong* when no η2' with |η2' − η2| < θ has it (outside ±θ of both thresholds: any tier but
the true one; inside one zone, a tier beyond the zone's two). Every rule computes its worst wrong-tier
probability exactly — dynamic programming over its stopping rule (`uqdrive.uq.stopping`) at every η2 of a grid
of `GRID` points plus each threshold and both zone edges — once per setting and process, and refuses a setting
whose error exceeds γ (`tier_rule` keeps each setting's rule, so a controller or a calibration pays that once
per process). A threshold of 0 always passes and one of 1 passes only when every draw to the cap agrees
(the calibration's never-firing and always-warning candidates), so every threshold in [0, 1] has a rule.
The middle tier is guaranteed (some η2 gets it with probability ≥ 1 − γ) only when δ1 − δ2 ≥ 2θ.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from uqdrive.uq.bounds import check_unit
from uqdrive.uq.stopping import stop_points
from uqdrive.uq.threshold import ThresholdTest, doubling_looks

CONFIDENT, UNSURE, DOUBTFUL = 0, 1, 2
"""The tiers: η2 ≥ δ1, δ2 ≤ η2 < δ1, η2 < δ2 (a warning controller's no warning or warning 0, warning 1,
warning 2)."""
UNDECIDED = -1
"""A look at which the rule draws on (in a rule's tables); also an unread look in recorded counts."""
GRID = 2001
"""η2 grid points (0, 1/2000, …, 1) the exact error is taken over, besides the thresholds and zone edges."""
_TOLERANCE = 1e-12  # η2 within this of a zone's edge counts as on the edge (0.7 − 0.05 is 0.6499999999999999)


@dataclass(frozen=True)
class TierResult:
    """The frame's ``tier`` after ``n`` draws, ``k`` of them within ε of π(o)."""

    tier: int
    n: int
    k: int


class _EdgeTest:
    """A forced test of "η2 ≥ 0" (always above, on no draw) or of "η2 ≥ 1" (below at the first contrary draw's
    look, above only when all of the cap's draws agree): the thresholds no `ThresholdTest` takes."""

    def __init__(self, threshold: float, looks: tuple[int, ...]):
        self.threshold, self.cap = threshold, looks[-1]

    def decide(self, k: int, n: int) -> str | None:
        if self.threshold == 0:
            return "above"
        if k < n:
            return "below"
        return "above" if n == self.cap else None


class TierRule(abc.ABC):
    """What both tier rules share: their looks, per-look decision tables (read by the controller through `run`
    and by the calibration's replay through `tiers`: one rule, two readers), the exact error and its check.
    A subclass sets ``delta1``, ``delta2``, ``theta``, ``gamma``, ``looks``, defines `decide` and calls `_settle`."""

    scheme: str
    delta1: float
    delta2: float
    theta: float
    gamma: float
    looks: tuple[int, ...]

    @classmethod
    @abc.abstractmethod
    def of(cls, delta1: float, delta2: float, gamma: float, theta: float, look: int, cap: int) -> TierRule:
        """The rule of a setting: thresholds, (θ, γ), first look and cap (`tier_rule` keeps each)."""

    @abc.abstractmethod
    def decide(self, k: int, n: int) -> int | None:
        """The tier after n draws (a look) with k successes; None: draw on."""

    def _settle(self) -> None:
        """Tabulate the decisions, compute the exact error (once per setting and process) and refuse one above γ."""
        self.tables = tuple(
            np.array([UNDECIDED if (t := self.decide(k, n)) is None else t for k in range(n + 1)], np.int8)
            for n in self.looks
        )
        if (self.tables[-1] == UNDECIDED).any():
            raise ValueError(f"the tier rule leaves frames undecided at its cap of {self.looks[-1]} draws")
        self.error = _exact_error(self)
        if self.error > self.gamma:
            raise ValueError(
                f"{self.describe()}: its exact wrong-tier error is {self.error:.4f} > gamma={self.gamma:g}; widen "
                "theta, raise the cap or set the thresholds further apart"
            )

    @property
    def reads_draws(self) -> bool:
        """False when every frame is confident on no draw (δ1 = 0: the never-firing thresholds)."""
        return self.delta1 > 0

    @property
    def middle_guaranteed(self) -> bool:
        """Whether some η2 gets the middle tier with probability ≥ 1 − γ: only when δ1 − δ2 ≥ 2θ (otherwise every
        η2 of the middle tier lies within θ of a threshold, where either neighbouring tier is acceptable)."""
        return self.delta1 - self.delta2 >= 2 * self.theta - _TOLERANCE

    def run(self, draw: Callable[[int], np.ndarray]) -> TierResult:
        """Draw look by look (``draw(m)``: m more 0/1 outcomes) until the tier is decided (at the cap at latest)."""
        if not self.reads_draws:
            return TierResult(CONFIDENT, 0, 0)
        k = n = 0
        for table, look in zip(self.tables, self.looks):
            k, n = k + int(np.asarray(draw(look - n)).sum()), look
            if table[k] != UNDECIDED:
                break
        return TierResult(int(table[k]), n, k)

    def tiers(self, counts: np.ndarray) -> np.ndarray:
        """The tier of each frame from its recorded counts [..., len(looks)] (successes among the first n draws at
        each look; `UNDECIDED` where unread): what `run` decides on the same stream."""
        counts = np.asarray(counts, np.int64)
        if counts.shape[-1] != len(self.looks):
            raise ValueError(f"counts have {counts.shape[-1]} looks per frame; this rule reads {len(self.looks)}")
        if not self.reads_draws:
            return np.full(counts.shape[:-1], CONFIDENT, np.int8)
        tier = np.full(counts.shape[:-1], UNDECIDED, np.int8)
        for j, table in enumerate(self.tables):
            k = counts[..., j]
            here = np.where(k >= 0, table[np.clip(k, 0, len(table) - 1)], UNDECIDED)
            tier = np.where(tier == UNDECIDED, here, tier)
        if (tier == UNDECIDED).any():
            raise ValueError("some frames' recorded counts end before the rule decides their tier")
        return tier

    def describe(self) -> str:
        return (
            f"{self.scheme} tier rule delta1={self.delta1:g}, delta2={self.delta2:g}, theta={self.theta:g}, "
            f"gamma={self.gamma:g}, looks {'/'.join(map(str, self.looks))}"
        )

    def settings(self) -> dict:
        """Plain values for records: the rule, its exact error and whether the middle tier is guaranteed."""
        return {
            "scheme": self.scheme,
            "delta1": self.delta1,
            "delta2": self.delta2,
            "theta": self.theta,
            "gamma": self.gamma,
            "looks": list(self.looks),
            "wrong_tier_error": self.error,
            "middle_guaranteed": self.middle_guaranteed,
        }


def _check(delta1: float, delta2: float, gamma: float, theta: float) -> tuple[float, float, float, float]:
    if not 0 <= delta2 <= delta1 <= 1:
        raise ValueError(f"tiers need 0 <= delta2 <= delta1 <= 1, got delta1={delta1!r}, delta2={delta2!r}")
    if not 0 < theta < 1:
        raise ValueError(f"theta must be in (0, 1), got {theta!r}")
    return float(delta1), float(delta2), check_unit("gamma", gamma), float(theta)


class TierTest(TierRule):
    """η2's tier for thresholds 0 ≤ ``delta2`` ≤ ``delta1`` ≤ 1 by two sequential tests at γ/2 each (module
    docstring); the first look has ``look`` draws, each later one doubles the total, up to ``cap``. A zone that
    reaches past 0 or 1 is clipped there. Refuses (``ValueError``, one line) a setting whose exact error exceeds
    ``gamma``."""

    scheme = "sequential"

    def __init__(self, delta1: float, delta2: float, gamma: float, theta: float, look: int, cap: int):
        self.delta1, self.delta2, self.gamma, self.theta = _check(delta1, delta2, gamma, theta)
        self.looks = doubling_looks(look, cap)
        self.upper, self.lower = (
            _EdgeTest(d, self.looks) if d in (0, 1) else ThresholdTest(d, self.gamma / 2, self.looks, self.theta)
            for d in (self.delta1, self.delta2)
        )
        self._settle()

    @classmethod
    def of(cls, delta1: float, delta2: float, gamma: float, theta: float, look: int, cap: int) -> TierTest:
        return cls(delta1, delta2, gamma, theta, look, cap)

    def decide(self, k: int, n: int) -> int | None:
        upper = self.upper.decide(k, n)
        if upper == "above":
            return CONFIDENT
        lower = self.lower.decide(k, n)
        if lower == "below":
            return DOUBTFUL
        return UNSURE if upper == "below" and lower == "above" else None


class FixedTier(TierRule):
    """The paper's tier: n draws at once (one look at ``cap``), the tier of η̂2 = k/n."""

    scheme = "fixed"

    def __init__(self, delta1: float, delta2: float, gamma: float, theta: float, cap: int):
        self.delta1, self.delta2, self.gamma, self.theta = _check(delta1, delta2, gamma, theta)
        self.looks = (int(cap),)
        self._settle()

    @classmethod
    def of(cls, delta1: float, delta2: float, gamma: float, theta: float, look: int, cap: int) -> FixedTier:
        return cls(delta1, delta2, gamma, theta, cap)  # one look: at the cap

    def decide(self, k: int, n: int) -> int | None:
        estimate = k / n
        return DOUBTFUL if estimate < self.delta2 else UNSURE if estimate < self.delta1 else CONFIDENT


def acceptable_tiers(etas: np.ndarray, delta1: float, delta2: float, theta: float) -> np.ndarray:
    """[tier, η2]: is the tier that of some η2' in [0, 1] with |η2' − η2| < θ? Tier regions: [δ1, 1], [δ2, δ1),
    [0, δ2), the last two possibly empty."""
    regions = ((delta1, 1.0), (delta2, delta1), (0.0, delta2))
    rows = []
    for tier, (low, high) in enumerate(regions):
        empty = tier != CONFIDENT and low >= high
        inside = (etas >= low) & ((etas <= high) if tier == CONFIDENT else (etas < high))
        distance = np.maximum(np.maximum(low - etas, etas - high), 0.0)
        rows.append((inside | (distance < theta - _TOLERANCE)) & (not empty))
    return np.array(rows)


def error_grid(delta1: float, delta2: float, theta: float) -> np.ndarray:
    """`GRID` points on [0, 1] plus both thresholds and their zones' edges (clipped to [0, 1])."""
    edges = [d + s * theta for d in (delta1, delta2) for s in (-1, 0, 1)]
    return np.union1d(np.linspace(0.0, 1.0, GRID), np.clip(edges, 0.0, 1.0))


@lru_cache(maxsize=1024)
def tier_rule(
    kind: type[TierRule], delta1: float, delta2: float, gamma: float, theta: float, look: int, cap: int
) -> TierRule:
    """The tier rule of a setting (``kind``: `TierTest` or `FixedTier`, whose ``look`` is unused), built and its
    exact error computed once per process: a controller and a calibration's candidates share it (read-only)."""
    return kind.of(delta1, delta2, gamma, theta, look, cap)


def _exact_error(rule: TierRule) -> float:
    """The worst probability over `error_grid` that ``rule`` reports a wrong tier, exactly: its stop points by
    dynamic programming, each weighed by its binomial probability at every η2 (milliseconds: bench tier)."""
    if not rule.reads_draws:
        return 0.0
    index = {n: j for j, n in enumerate(rule.looks)}

    def stops(n: int, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tier = rule.tables[index[n]][counts]
        return tier != UNDECIDED, tier

    points = stop_points(rule.looks, stops)
    (tier,) = points.labels
    etas = error_grid(rule.delta1, rule.delta2, rule.theta)
    probs = points.masses(etas, [lambda near, _, t=t: tier[near, None] == t for t in (CONFIDENT, UNSURE, DOUBTFUL)])
    wrong = ~acceptable_tiers(etas, rule.delta1, rule.delta2, rule.theta)
    return float((probs * wrong).sum(0).max())
