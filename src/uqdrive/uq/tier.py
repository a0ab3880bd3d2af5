"""The η2 tier of a frame — η2 ≥ δ1, δ2 ≤ η2 < δ1 or η2 < δ2 — decided by two sequential threshold tests on one
stream of Bernoulli draws, with a per-frame error ≤ γ.

Each draw is 1 when a fresh weight sample's decision lies within ε of π(o) (rate η2). Two forced
`ThresholdTest`s at level γ/2, of δ1 and of δ2, share the draws and the looks (doubling from ``look`` to the
cap), and the frame stops at the first look that settles its tier: δ1's test says "above" (tier 0), δ2's says
"below" (tier 2), or δ1's says "below" while δ2's says "above" (tier 1). At the cap both tests are forced (by
the point estimate), so every frame ends with a tier. Guarantee: P(wrong tier) ≤ γ whenever η2 is at least θ
from both thresholds (each test errs with probability ≤ γ/2 outside its own zone, and a wrong tier needs one of
them to err); `tests/test_uq_tier.py` computes the joint error exactly, by dynamic programming over this
stopping rule, on a fine η2 grid.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from uqdrive.uq.threshold import ThresholdTest, doubling_looks

CONFIDENT, UNSURE, DOUBTFUL = 0, 1, 2
"""The tiers: η2 ≥ δ1, δ2 ≤ η2 < δ1, η2 < δ2 (a warning controller's no warning or warning 0, warning 1,
warning 2)."""


@dataclass(frozen=True)
class TierResult:
    """The frame's ``tier`` after ``n`` draws, ``k`` of them within ε of π(o)."""

    tier: int
    n: int
    k: int


class TierTest:
    """η2's tier for thresholds ``delta1`` ≥ ``delta2``, error ≤ ``gamma`` outside ±``theta`` of each; the first
    look has ``look`` draws, each later one doubles the total, up to ``cap``. A zone that reaches past 0 or 1 is
    clipped there; thresholds of 0 or 1 themselves are refused (no test certifies η2 ≥ 1)."""

    def __init__(self, delta1: float, delta2: float, gamma: float, theta: float, look: int, cap: int):
        if not 0 < delta2 <= delta1 < 1:
            raise ValueError(
                f"sequential tiers need 0 < delta2 <= delta1 < 1, got delta1={delta1!r}, delta2={delta2!r}"
            )
        self.looks = doubling_looks(look, cap)
        self.upper = ThresholdTest(delta1, gamma / 2, self.looks, theta)
        self.lower = ThresholdTest(delta2, gamma / 2, self.looks, theta)

    @property
    def first_draws(self) -> int:
        """OutcomeStream worth making in a frame's first head call: the first two looks (all draws agreeing settle a
        tier at δ1 = 0.7 and γ = 0.05 from 9 draws, so the second look, not the first)."""
        return self.looks[min(1, len(self.looks) - 1)]

    def decide(self, k: int, n: int) -> int | None:
        """The tier after n draws (a look) with k successes; None: draw on."""
        upper = self.upper.decide(k, n)
        if upper == "above":
            return CONFIDENT
        lower = self.lower.decide(k, n)
        if lower == "below":
            return DOUBTFUL
        return UNSURE if upper == "below" and lower == "above" else None

    def run(self, draw: Callable[[int], np.ndarray]) -> TierResult:
        """Draw look by look (``draw(m)``: m more 0/1 outcomes) until the tier is decided (at the cap at latest)."""
        k = n = 0
        for look in self.looks:
            k, n = k + int(np.asarray(draw(look - n)).sum()), look
            tier = self.decide(k, n)
            if tier is not None:
                break
        return TierResult(tier, n, k)  # both tests are forced: the cap decides
